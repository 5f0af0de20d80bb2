/* libFuzzer target: the ground model reader (common/pb_ground) on arbitrary bytes, read
 * both as the PGM behind a fixed, valid ground.yaml (4 x 3 corners) and as the blocked
 * file behind a ground.yaml of 70 x 3 corners (two blocks) that counts the blocks the
 * input's size holds, then lookups on what it read.
 * fuzz-sources: common/pb_ground.c common/pb_config.c common/pb_err.c
 * fuzz-max-len: 20000 */
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

static void load(const char *yaml)
{
    pb_err_t err;
    err.msg[0] = 0;
    pb_ground_t *g = pb_ground_load(yaml, &err);
    if (g) {
        double z, r, p;
        for (double x = -0.5; x < 18.5; x += 0.37)
            for (double y = -0.5; y < 1.5; y += 0.29)
                if (pb_ground_height(g, x, y, &z) == 0 && !isfinite(z)) abort();
        pb_ground_car(g, 0.2, 0.3, 0.1, 0.8, 0.6, &z, &r, &p);
        pb_ground_car(g, 15.9, 0.3, 0.1, 0.8, 0.6, &z, &r, &p);   /* across the blocks' border */
        pb_ground_destroy(g);
    } else if (!err.msg[0]) {
        abort();    /* a refusal always says why */
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static char dir[64];
    static char yaml[128], pgm[128], byaml[128], blocks[128];
    if (!dir[0]) {
        snprintf(dir, sizeof dir, "/tmp/fuzz_ground_%d", (int)getpid());
        mkdir(dir, 0700);
        snprintf(yaml, sizeof yaml, "%s/g.yaml", dir);
        snprintf(pgm, sizeof pgm, "%s/g.pgm", dir);
        snprintf(byaml, sizeof byaml, "%s/b.yaml", dir);
        snprintf(blocks, sizeof blocks, "%s/b.blocks", dir);
        static const char text[] = "origin_x: 0\norigin_y: 0\ncell_m: 0.5\nwidth: 4\nheight: 3\nz0_m: 1.0\nscale_m: 0.001\nfile: g.pgm\n";
        if (fuzz_write_file(yaml, text, sizeof text - 1)) abort();
    }
    if (fuzz_write_file(pgm, data, size) || fuzz_write_file(blocks, data, size)) return 0;
    load(yaml);
    /* the blocks the input's size holds (a record: 8 + 2 x 64 x 64 + 8 bytes after the 8 of the magic) */
    char text[256];
    int n = snprintf(text, sizeof text, "origin_x: 0\norigin_y: 0\ncell_m: 0.25\nwidth: 70\nheight: 3\nz0_m: 1.0\n"
                     "scale_m: 0.001\nblock: 64\nblocks: %zu\nfile: b.blocks\n", size > 8 ? (size - 8) / 8208 : 0);
    if (fuzz_write_file(byaml, text, (size_t)n)) abort();
    load(byaml);
    return 0;
}
