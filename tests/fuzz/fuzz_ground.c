/* libFuzzer target: the ground model reader (common/pb_ground) on arbitrary PGM bytes
 * behind a fixed, valid ground.yaml (4 x 3 corners), then lookups on what it read.
 * fuzz-sources: common/pb_ground.c common/pb_config.c common/pb_err.c */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fuzz_common.h"
#include "pb_ground.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char dir[64];
    static char yaml[128], pgm[128];
    if (!dir[0]) {
        snprintf(dir, sizeof dir, "/tmp/fuzz_ground_%d", (int)getpid());
        mkdir(dir, 0700);
        snprintf(yaml, sizeof yaml, "%s/g.yaml", dir);
        snprintf(pgm, sizeof pgm, "%s/g.pgm", dir);
        static const char text[] = "origin_x: 0\norigin_y: 0\ncell_m: 0.5\nwidth: 4\nheight: 3\nz0_m: 1.0\nscale_m: 0.001\nfile: g.pgm\n";
        if (fuzz_write_file(yaml, text, sizeof text - 1)) abort();
    }
    if (fuzz_write_file(pgm, data, size)) return 0;
    pb_err_t err;
    pb_ground_t *g = pb_ground_load(yaml, &err);
    if (g) {
        double z, r, p;
        for (double x = -0.5; x < 2.5; x += 0.37)
            for (double y = -0.5; y < 1.5; y += 0.29)
                if (pb_ground_height(g, x, y, &z) == 0 && !isfinite(z)) abort();
        pb_ground_car(g, 0.2, 0.3, 0.1, 0.8, 0.6, &z, &r, &p);
        pb_ground_destroy(g);
    } else if (!err.msg[0]) {
        abort();    /* a refusal always says why */
    }
    return 0;
}
