/* pb_geo and pb_math against known values and round trips. */
#include "pb_check.h"
#include "pb_geo.h"
#include "pb_math.h"

int main(void)
{
    pb_georef_t g = { 40.7580, -73.9540, 10.0, 0.0 };
    double lat, lon, alt;

    /* The origin maps to the geo-reference. */
    double o[3] = { 0, 0, 0 };
    pb_geo_map_to_wgs84(&g, o, &lat, &lon, &alt);
    CHECK_NEAR(lat, 40.7580, 1e-10);
    CHECK_NEAR(lon, -73.9540, 1e-10);
    CHECK_NEAR(alt, 10.0, 1e-6);

    /* 1 km north along +y (yaw 0: x east): latitude grows by 1000 / M, M the meridian
     * radius of curvature a(1-e^2)/(1-e^2 sin^2 lat)^1.5 = 6,363,827 m at 40.758 deg. */
    double north[3] = { 0, 1000, 0 };
    pb_geo_map_to_wgs84(&g, north, &lat, &lon, &alt);
    double s = sin(40.7580 * M_PI / 180), e2 = 0.00669437999014;
    double M = 6378137.0 * (1 - e2) / pow(1 - e2 * s * s, 1.5);
    CHECK_NEAR((lat - 40.7580) * M_PI / 180 * M, 1000.0, 0.5);   /* curvature over 1 km: < 0.5 m */
    CHECK_NEAR(lon, -73.9540, 1e-9);
    CHECK(alt > 10.0 && alt < 10.2);   /* the tangent plane rises above the ellipsoid: 1000^2/(2R) = 0.078 m */

    /* Round trips at several yaws and distances: sub-millimetre. */
    double yaws[] = { 0, 29.5, -120, 180 };
    for (int k = 0; k < 4; k++) {
        g.yaw_deg = yaws[k];
        double p[3] = { 1234.5, -876.25, 3.5 }, q[3];
        pb_geo_map_to_wgs84(&g, p, &lat, &lon, &alt);
        pb_geo_wgs84_to_map(&g, lat, lon, alt, q);
        CHECK_NEAR(q[0], p[0], 1e-3);
        CHECK_NEAR(q[1], p[1], 1e-3);
        CHECK_NEAR(q[2], p[2], 1e-3);
    }
    /* yaw 90: map +x points north. */
    g.yaw_deg = 90;
    double px[3] = { 100, 0, 0 }, enu[3];
    pb_geo_map_to_enu_vec(&g, px, enu);
    CHECK_NEAR(enu[0], 0, 1e-9);
    CHECK_NEAR(enu[1], 100, 1e-9);

    /* Quaternions: rpy round trip, matrix round trip, transform inverse. */
    double q[4], r, p, y;
    pb_quat_from_rpy(0.1, -0.2, 2.5, q);
    pb_quat_to_rpy(q, &r, &p, &y);
    CHECK_NEAR(r, 0.1, 1e-12);
    CHECK_NEAR(p, -0.2, 1e-12);
    CHECK_NEAR(y, 2.5, 1e-12);
    double R[9], q2[4];
    pb_quat_to_matrix(q, R);
    pb_matrix_to_quat(R, q2);
    for (int i = 0; i < 4; i++) CHECK_NEAR(q2[i], q[i] * (q[0] < 0 ? -1 : 1), 1e-12);
    double v[3] = { 1, 0, 0 }, w[3];
    pb_quat_from_rpy(0, 0, M_PI / 2, q);
    pb_quat_rotate(q, v, w);
    CHECK_NEAR(w[0], 0, 1e-12);
    CHECK_NEAR(w[1], 1, 1e-12);
    pb_transform_t a = { { 1, 2, 3 }, { 0 } }, ai, id;
    pb_quat_from_rpy(0.3, 0.1, -1.0, a.q);
    pb_transform_inverse(&a, &ai);
    pb_transform_compose(&a, &ai, &id);
    CHECK_NEAR(id.t[0], 0, 1e-12);
    CHECK_NEAR(id.t[2], 0, 1e-12);
    CHECK_NEAR(fabs(id.q[0]), 1, 1e-12);
    CHECK_NEAR(pb_wrap_angle(3 * M_PI), M_PI, 1e-12);
    CHECK_NEAR(pb_wrap_angle(-M_PI / 2 - 4 * M_PI), -M_PI / 2, 1e-12);
    return pb_check_report("test_geo_math");
}
