/* gnss-bench: parse throughput of the gnss core on a buffer built from capture files.
 *   gnss-bench --runs N --repeat-to BYTES FILE...
 * Concatenates FILEs, repeats them up to BYTES, and times gnss_driver_feed + finish over
 * the whole buffer N times (process CPU time). Prints one JSON line: bytes, frames,
 * fixes, errors and the per-run seconds. Used by `make bench-gnss`. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "gnss_driver.h"
#include "pb_clock.h"
#include "pb_opt.h"

static int64_t fixes;
static double lat_sum;
static void on_fix(void *user, const gnss_fix_out_t *f) { fixes++; lat_sum += f->lat_deg == f->lat_deg ? f->lat_deg : 0; }

static void usage(FILE *f)
{
    fprintf(f, "usage: gnss-bench [--runs N] [--repeat-to BYTES] FILE...\n"
               "Times the gnss parser core over FILEs repeated to BYTES; prints JSON.\n");
}

int main(int argc, char **argv)
{
    long runs = 5, target = 4 << 20;
    const pb_opt_t opts[] = {
        PB_OPT_LONG("runs", &runs, 1, 1000), PB_OPT_LONG("repeat-to", &target, 1, 1L << 31), PB_OPT_END,
    };
    int parsed = pb_opt_parse("gnss-bench", opts, usage, PB_OPT_ARGS, argc, argv);
    if (parsed >= 0) return parsed;
    int i = optind;
    if (i >= argc) { fprintf(stderr, "gnss-bench: no input files\n"); return 2; }
    uint8_t *one = NULL;
    size_t n1 = 0;
    for (; i < argc; i++) {
        FILE *f = fopen(argv[i], "rb");
        if (!f) { perror(argv[i]); return 1; }
        fseek(f, 0, SEEK_END);
        long sz = ftell(f);
        fseek(f, 0, SEEK_SET);
        one = realloc(one, n1 + (size_t)sz);
        if (fread(one + n1, 1, (size_t)sz, f) != (size_t)sz) { perror(argv[i]); return 1; }
        n1 += (size_t)sz;
        fclose(f);
    }
    size_t reps = ((size_t)target + n1 - 1) / n1;
    size_t n = reps * n1;
    uint8_t *buf = malloc(n);
    for (size_t r = 0; r < reps; r++) memcpy(buf + r * n1, one, n1);

    printf("{\"bytes\": %zu, \"seconds\": [", n);
    int64_t frames = 0, errors = 0, nfix = 0;
    for (long r = 0; r < runs; r++) {
        fixes = 0;
        gnss_driver_handlers_t h = { .on_fix = on_fix };
        gnss_driver_t *d = gnss_driver_create(NULL, &h);
        double t0 = pb_clock_process_cpu_ms() * 1e-3;
        /* 4 KB reads, like a serial port or file reader would hand over. */
        for (size_t off = 0; off < n; off += 4096)
            gnss_driver_feed(d, buf + off, n - off < 4096 ? n - off : 4096);
        gnss_driver_finish(d);
        double t = pb_clock_process_cpu_ms() * 1e-3 - t0;
        printf("%s%.6f", r ? ", " : "", t);
        frames = gnss_driver_counter(d, GNSS_C_UBX_FRAMES) + gnss_driver_counter(d, GNSS_C_NMEA_SENTENCES) +
                 gnss_driver_counter(d, GNSS_C_RTCM3_FRAMES);
        errors = 0;
        for (int c = GNSS_C_FIRST_ERROR; c < GNSS_C_COUNT; c++) errors += gnss_driver_counter(d, (gnss_counter_t)c);
        nfix = fixes;
        gnss_driver_destroy(d);
    }
    printf("], \"frames\": %lld, \"ubx_nav_pvt_fixes\": %lld, \"errors\": %lld, \"checksum\": %.6f}\n",
           (long long)frames, (long long)nfix, (long long)errors, lat_sum);
    free(buf);
    free(one);
    return 0;
}
