/* libFuzzer target: one candump -l line, arbitrary bytes. A frame it returns must be
 * self-consistent; an error must point at a column inside the line.
 * fuzz-sources: common/pb_candump.c common/pb_err.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pb_candump.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    pb_candump_frame_t f;
    size_t col = 0;
    int r = pb_candump_parse((const char *)data, size, &f, &col);
    if (r == PB_CANDUMP_FRAME) {
        if (f.len > (f.fd ? 64 : 8)) abort();
        if (!f.extended && !f.error && f.id > 0x7FF) abort();
        if (f.id > 0x1FFFFFFF) abort();
        if (memchr(f.iface, 0, sizeof f.iface) == NULL || f.iface[0] == 0) abort();
        for (int i = f.len; i < 64; i++) if (f.data[i]) abort();
    } else if (r < 0) {
        if (col < 1 || col > size + 1) abort();
        if (!pb_candump_strerror(r)) abort();
    } else if (r != PB_CANDUMP_BLANK) {
        abort();
    }
    return 0;
}
