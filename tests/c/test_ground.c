/* Unit tests of common/pb_ground: save/load round trip (mm quantum), unknown cells,
 * bilinear lookup, the car's z/roll/pitch, and refused files. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_ground.h"

int main(void)
{
    char dir[] = "/tmp/test_ground_XXXXXX";
    if (!mkdtemp(dir)) return 1;
    char path[256], pgm[256];
    snprintf(path, sizeof path, "%s/g.yaml", dir);
    snprintf(pgm, sizeof pgm, "%s/g.pgm", dir);
    /* a plane rising 5 % along x and falling 2 % along y, a hole at (3, 3) */
    pb_ground_t *g = pb_ground_create(-1, -2, 0.5, 21, 11);
    for (int j = 0; j < 11; j++)
        for (int i = 0; i < 21; i++) pb_ground_set(g, i, j, 100 + 0.05 * (-1 + i * 0.5) - 0.02 * (-2 + j * 0.5));
    pb_ground_set(g, 8, 10, NAN);
    pb_err_t err = { "" };
    CHECK(pb_ground_save(g, path, &err) == 0);
    pb_ground_t *h = pb_ground_load(path, &err);
    CHECK(h != NULL);
    if (!h) { fprintf(stderr, "%s\n", err.msg); return 1; }
    double z;
    CHECK(pb_ground_height(h, 2.3, 0.7, &z) == 0 && fabs(z - (100 + 0.05 * 2.3 - 0.02 * 0.7)) < 0.001);
    CHECK(isnan(pb_ground_get(h, 8, 10)));
    CHECK(pb_ground_height(h, 50, 0, &z) == -1);        /* outside */
    double roll, pitch;
    CHECK(pb_ground_car(h, 0, 0, 0, 2.7, 1.5, &z, &roll, &pitch) == 0);
    CHECK(fabs(pitch + atan(0.05)) < 1e-3);             /* uphill: nose up, pitch < 0 */
    CHECK(fabs(roll - atan(-0.02)) < 1e-3);             /* left side (+y) lower */
    CHECK(fabs(z - 100) < 0.002);
    pb_ground_destroy(h);
    /* refused: a truncated PGM, a wrong header, a bad YAML key */
    FILE *f = fopen(pgm, "r+b");
    CHECK(f != NULL);
    if (f) { CHECK(ftruncate(fileno(f), 100) == 0); fclose(f); }
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "g.pgm") && strstr(err.msg, "byte"));
    f = fopen(pgm, "wb");
    fputs("P2\n21 11\n65535\n", f);
    fclose(f);
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "P5"));
    f = fopen(path, "a");
    fputs("colour: red\n", f);
    fclose(f);
    h = pb_ground_load(path, &err);
    CHECK(h == NULL && strstr(err.msg, "g.yaml:") && strstr(err.msg, "colour"));
    pb_ground_destroy(g);
    unlink(path); unlink(pgm); rmdir(dir);
    return pb_check_report("test_ground");
}
