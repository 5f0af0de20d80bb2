/* libFuzzer target: the strict event-log reader on arbitrary bytes. Every event it
 * returns must lie inside the file; a damaged file must end in an error, never a crash.
 * fuzz-sources: common/pb_log.c common/pb_err.c build/gen/c/portobello_pose_t.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"
#include "pb_log.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *path = fuzz_input_file("log", "", data, size);
    if (!path) return 0;
    pb_err_t err;
    pb_log_t *log = pb_log_open_read(path, &err);
    if (!log) return 0;
    pb_event_t ev;
    int r;
    int64_t end = 0;
    while ((r = pb_log_next(log, &ev, &err)) == 1) {
        if (ev.offset < end || ev.offset + 28 + (int64_t)strlen(ev.channel) + ev.datalen > (int64_t)size) abort();
        end = ev.offset + 28 + (int64_t)strlen(ev.channel) + ev.datalen;
        volatile uint8_t sink = 0;
        for (int32_t i = 0; i < ev.datalen; i++) sink ^= ev.data[i];
        (void)sink;
    }
    if (r < 0 && strstr(err.msg, "byte ") == NULL) abort();   /* every error names its offset */
    pb_log_close(log, NULL);
    return 0;
}
