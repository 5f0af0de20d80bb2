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

    /* Beam gaps of the range image: the largest ring gap (0.3 rad), 2 pi / cols. */
    double ring_gap = 0, col_gap = 0;
    CHECK(pb_scan_points(&s, &pts, &err) == 7);
    CHECK(pb_scan_beam_gaps(&s, &pts, &ring_gap, &col_gap) == 1);
    CHECK_NEAR(ring_gap, 0.3, 1e-6);
    CHECK_NEAR(col_gap, M_PI / 2, 1e-12);

    /* Point form: (0, 0, 0) is no return; no rings, so the gaps are not known. */
    px[1] = 0; py[1] = 0;
    CHECK(pb_scan_points(&p, &pts, &err) == 1);
    CHECK(pb_scan_beam_gaps(&p, &pts, &ring_gap, &col_gap) == 0);

    /* Point form with rings: 3 rings at -0.1, 0 and 0.2 rad (gap 0.2), 40 points on the
     * fullest ring (column gap 2 pi / 40), a few points off their ring's elevation */
    enum { NP = 40 + 30 + 20 };
    float qx[NP], qy[NP], qz[NP], qi[NP] = { 0 };
    int32_t qo[NP] = { 0 };
    uint8_t qr[NP];
    const double ring_el[3] = { -0.1, 0.0, 0.2 };
    const int ring_n[3] = { 40, 30, 20 };
    int k = 0;
    for (int r = 0; r < 3; r++)
        for (int j = 0; j < ring_n[r]; j++, k++) {
            double az = 2 * M_PI * j / ring_n[r], el = ring_el[r] + (j == 3 ? 0.05 : 0), d = 10 + j % 7;
            qx[k] = (float)(d * cos(el) * cos(az)); qy[k] = (float)(d * cos(el) * sin(az)); qz[k] = (float)(d * sin(el));
            qr[k] = (uint8_t)(5 + r);
        }
    portobello_lidar_scan_t q = { 0 };
    q.npoints = NP; q.x = qx; q.y = qy; q.z = qz; q.intensity = qi; q.point_offset_us = qo; q.ring = qr;
    CHECK(pb_scan_points(&q, &pts, &err) == NP);
    CHECK(pb_scan_beam_gaps(&q, &pts, &ring_gap, &col_gap) == 1);
    CHECK_NEAR(ring_gap, 0.2, 1e-5);
    CHECK_NEAR(col_gap, 2 * M_PI / 40, 1e-12);
    pb_points_free(&pts);
    return pb_check_report("test_scan");
}
