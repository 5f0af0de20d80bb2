/* import-candump: a `candump -l` text log -> CAN_FRAME events in an LCM log.
 *
 * Every frame is kept, in file order; the event timestamp is the frame's own
 * time. The first bad line stops the import with FILE:LINE:COL and a non-zero
 * exit, after the frames before it have been written and the log closed, so
 * OUT is always a valid log of a prefix of the input. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "pb_candump.h"
#include "pb_err.h"
#include "pb_log.h"
#include "pb_progress.h"
#include "portobello_can_frame_t.h"

static void usage(FILE *f)
{
    fprintf(f,
        "usage: import-candump --in FILE.log --out OUT.lcm [--channel CAN_FRAME] [--quiet]\n"
        "\n"
        "Turns a `candump -l` log (lines \"(1533226488.434433) can0 0B4#000000001D0B7A5E\")\n"
        "into CAN_FRAME events (portobello.can_frame_t), one per line, in file order.\n"
        "Classic, 29-bit, remote (#R), CAN FD (##) and error frames are kept.\n"
        "  utime / event time : the line's timestamp in microseconds (exact)\n"
        "  bus                : N of canN; other interface names get %d, %d, ... in order\n"
        "                       of first appearance (listed on stderr)\n"
        "A bad line stops the import: FILE:LINE:COL: what, exit 1; the frames before it\n"
        "are in OUT, which is closed cleanly.\n"
        "  --channel NAME  LCM channel (default CAN_FRAME)\n"
        "  --quiet         no progress bar or summary\n",
        PB_CANDUMP_NAMED_BUS_BASE, PB_CANDUMP_NAMED_BUS_BASE + 1);
}

int main(int argc, char **argv)
{
    const char *in_path = NULL, *out_path = NULL, *channel = "CAN_FRAME";
    int quiet = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { usage(stdout); return 0; }
        else if (!strcmp(a, "--quiet")) quiet = 1;
        else if (i + 1 < argc && !strcmp(a, "--in")) in_path = argv[++i];
        else if (i + 1 < argc && !strcmp(a, "--out")) out_path = argv[++i];
        else if (i + 1 < argc && !strcmp(a, "--channel")) channel = argv[++i];
        else {
            fprintf(stderr, "import-candump: unknown or incomplete option '%s'\n", a);
            usage(stderr);
            return 2;
        }
    }
    if (!in_path || !out_path) {
        fprintf(stderr, "import-candump: --in and --out are required\n");
        usage(stderr);
        return 2;
    }

    FILE *in = fopen(in_path, "rb");
    if (!in) {
        fprintf(stderr, "import-candump: %s: %s\n", in_path, strerror(errno));
        return 1;
    }
    struct stat st;
    int64_t size = fstat(fileno(in), &st) == 0 ? (int64_t)st.st_size : 0;

    pb_err_t err;
    pb_log_t *out = pb_log_open_write(out_path, &err);
    if (!out) {
        fprintf(stderr, "import-candump: %s\n", err.msg);
        fclose(in);
        return 1;
    }

    pb_progress_t prog;
    pb_progress_start(&prog, "import-candump", size, quiet);

    static pb_candump_buses_t buses;
    char *line = NULL;
    size_t cap = 0;
    ssize_t got;
    long lineno = 0, frames = 0, blank = 0, nfd = 0, nerr = 0, nrtr = 0, next = 0;
    int64_t pos = 0;
    uint8_t buf[256];
    int status = 0;

    while ((got = getline(&line, &cap, in)) >= 0) {
        lineno++;
        pos += got;
        pb_candump_frame_t f;
        size_t col = 0;
        int rc = pb_candump_parse(line, (size_t)got, &f, &col);
        if (rc == PB_CANDUMP_BLANK) { blank++; continue; }
        if (rc != PB_CANDUMP_FRAME) {
            fprintf(stderr, "%s:%ld:%zu: %s\n", in_path, lineno, col, pb_candump_strerror(rc));
            status = 1;
            break;
        }
        int added, bus = pb_candump_bus(&buses, f.iface, &added);
        if (added && !quiet) fprintf(stderr, "import-candump: interface %s -> bus %d\n", f.iface, bus);
        if (bus < 0) {
            fprintf(stderr, "%s:%ld: more than %d interfaces not named canN\n", in_path, lineno, PB_CANDUMP_MAX_NAMED);
            status = 1;
            break;
        }
        portobello_can_frame_t m = {
            .utime = f.utime, .bus = (int16_t)bus, .id = (int32_t)f.id,
            .extended = f.extended, .rtr = f.rtr, .error = f.error, .fd = f.fd,
            .len = f.len, .data = f.data,
        };
        int n = portobello_can_frame_t_encode(buf, 0, (int)sizeof buf, &m);
        if (n < 0 || pb_log_write(out, f.utime, channel, buf, n, &err) != 0) {
            fprintf(stderr, "import-candump: %s\n", n < 0 ? "encoding failed" : err.msg);
            status = 1;
            break;
        }
        frames++;
        nfd += f.fd; nerr += f.error; nrtr += f.rtr; next += f.extended;
        if ((frames & 0xfff) == 0) pb_progress_update(&prog, pos);
    }
    if (status == 0 && ferror(in)) {
        fprintf(stderr, "import-candump: %s: read error: %s\n", in_path, strerror(errno));
        status = 1;
    }
    free(line);
    fclose(in);
    if (status == 0) pb_progress_finish(&prog);
    else if (prog.tty && !quiet) fputc('\n', stderr);  /* end the bar's line; it was not 100 % */

    /* Close even after a bad line: OUT must hold every frame before it. */
    if (pb_log_close(out, &err) != 0) {
        fprintf(stderr, "import-candump: %s\n", err.msg);
        status = 1;
    }
    if (!quiet || status)
        fprintf(stderr, "import-candump: %ld frames written to %s (%ld extended, %ld FD, %ld remote, "
                "%ld error; %ld blank lines)%s\n", frames, out_path, next, nfd, nrtr, nerr, blank,
                status ? " before the error" : "");
    return status;
}
