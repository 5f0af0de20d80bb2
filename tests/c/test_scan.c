/* pb_scan: the range-image model of lidar_scan_t.lcm, computed by hand. */
#include <stdlib.h>

#include "pb_check.h"
#include "pb_scan.h"

int main(void)
{
    enum { ROWS = 2, COLS = 4 };
    int32_t range[ROWS * COLS] = { 10000, 0, 20000, 5000, 1000, 2000, 3000, 4000 };
    uint8_t refl[ROWS * COLS] = { 1, 2, 3, 4, 5, 6, 7, 8 };
    int32_t cot[COLS] = { 0, 25000, 50000, 75000 };
    float alt[ROWS] = { 0.1f, -0.2f }, az[ROWS] = { 0.01f, -0.01f };
    portobello_lidar_scan_t s = { 0 };
    s.rows = ROWS; s.cols = COLS; s.npixels = ROWS * COLS;
    s.range_mm = range; s.reflectivity = refl; s.col_offset_us = cot;
    s.beam_altitude_rad = alt; s.beam_azimuth_rad = az; s.beam_origin_m = 0.015f;
    for (int i = 0; i < 4; i++) s.lidar_from_beam[i * 5] = 1;
    s.lidar_from_beam[11] = 0.036;   /* beam frame 3.6 cm above the lidar origin */

    pb_points_t pts = { 0 };
    pb_err_t err;
    CHECK(pb_scan_points(&s, &pts, &err) == 7);   /* one no-return pixel */

    /* Column 2 (enc = pi), row 0, 20 m: by hand from the documented formula. */
    double n = 0.015f, R = 20.0, enc = M_PI, th = enc + 0.01f, ph = 0.1f;
    double x = (R - n) * cos(th) * cos(ph) + n * cos(enc);
    double y = (R - n) * sin(th) * cos(ph) + n * sin(enc);
    double z = (R - n) * sin(ph) + 0.036;
    int found = 0;
    for (int i = 0; i < pts.n; i++)
        if (pts.offset_us[i] == 50000 && pts.ring[i] == 0) {
            found = 1;
            CHECK_NEAR(pts.x[i], x, 1e-4);
            CHECK_NEAR(pts.y[i], y, 1e-4);
            CHECK_NEAR(pts.z[i], z, 1e-4);
            CHECK(pts.intensity[i] == 3);
        }
    CHECK(found);

    /* Inconsistent sizes are refused. */
    s.npixels = 7;
    CHECK(pb_scan_points(&s, &pts, &err) == -1);
    CHECK_CONTAINS(err.msg, "npixels 7 != rows 2 x cols 4");
    s.npixels = ROWS * COLS;

    /* Point form: non-finite points are skipped. */
    float px[3] = { 1, NAN, 3 }, py[3] = { 0, 0, INFINITY }, pz[3] = { 0, 0, 0 }, pi[3] = { 9, 9, 9 };
    int32_t po[3] = { 0, 1, 2 };
    uint8_t pr[3] = { 255, 255, 255 };
    portobello_lidar_scan_t p = { 0 };
    p.npoints = 3; p.x = px; p.y = py; p.z = pz; p.intensity = pi; p.point_offset_us = po; p.ring = pr;
    CHECK(pb_scan_points(&p, &pts, &err) == 1);
    CHECK_NEAR(pts.x[0], 1, 0);
    pb_points_free(&pts);
    return pb_check_report("test_scan");
}
