/* Map frame <-> WGS84 through ECEF and the local ENU tangent plane at the origin. */
#include "pb_geo.h"

#include <math.h>

static const double WGS84_A = 6378137.0;
static const double WGS84_F = 1.0 / 298.257223563;
#define DEG (M_PI / 180.0)

static void geodetic_to_ecef(double lat, double lon, double h, double e[3])
{
    double e2 = WGS84_F * (2 - WGS84_F);
    double s = sin(lat), n = WGS84_A / sqrt(1 - e2 * s * s);
    e[0] = (n + h) * cos(lat) * cos(lon);
    e[1] = (n + h) * cos(lat) * sin(lon);
    e[2] = (n * (1 - e2) + h) * s;
}

static void ecef_to_geodetic(const double e[3], double *lat, double *lon, double *h)
{
    double e2 = WGS84_F * (2 - WGS84_F);
    double p = hypot(e[0], e[1]);
    *lon = atan2(e[1], e[0]);
    double la = atan2(e[2], p * (1 - e2)), n = WGS84_A;
    for (int i = 0; i < 8; i++) {   /* converges to < 1e-12 rad near the surface */
        double s = sin(la);
        n = WGS84_A / sqrt(1 - e2 * s * s);
        la = atan2(e[2] + e2 * n * s, p);
    }
    *lat = la;
    double s = sin(la);
    n = WGS84_A / sqrt(1 - e2 * s * s);
    *h = fabs(cos(la)) > 1e-9 ? p / cos(la) - n : fabs(e[2]) - n * (1 - e2);
}

/* ENU basis vectors at (lat, lon) as rows of R (ECEF -> ENU). */
static void enu_basis(double lat, double lon, double R[9])
{
    double sl = sin(lat), cl = cos(lat), so = sin(lon), co = cos(lon);
    R[0] = -so;      R[1] = co;       R[2] = 0;
    R[3] = -sl * co; R[4] = -sl * so; R[5] = cl;
    R[6] = cl * co;  R[7] = cl * so;  R[8] = sl;
}

void pb_geo_map_to_enu_vec(const pb_georef_t *g, const double v[3], double enu[3])
{
    double c = cos(g->yaw_deg * DEG), s = sin(g->yaw_deg * DEG);
    enu[0] = c * v[0] - s * v[1];
    enu[1] = s * v[0] + c * v[1];
    enu[2] = v[2];
}

void pb_geo_map_to_wgs84(const pb_georef_t *g, const double xyz[3], double *lat_deg, double *lon_deg, double *alt_m)
{
    double enu[3], o[3], R[9], e[3];
    pb_geo_map_to_enu_vec(g, xyz, enu);
    geodetic_to_ecef(g->lat0_deg * DEG, g->lon0_deg * DEG, g->alt0_m, o);
    enu_basis(g->lat0_deg * DEG, g->lon0_deg * DEG, R);
    for (int i = 0; i < 3; i++) e[i] = o[i] + R[i] * enu[0] + R[3 + i] * enu[1] + R[6 + i] * enu[2];
    double lat, lon;
    ecef_to_geodetic(e, &lat, &lon, alt_m);
    *lat_deg = lat / DEG;
    *lon_deg = lon / DEG;
}

void pb_geo_wgs84_to_map(const pb_georef_t *g, double lat_deg, double lon_deg, double alt_m, double xyz[3])
{
    double o[3], e[3], d[3], R[9], enu[3];
    geodetic_to_ecef(g->lat0_deg * DEG, g->lon0_deg * DEG, g->alt0_m, o);
    geodetic_to_ecef(lat_deg * DEG, lon_deg * DEG, alt_m, e);
    for (int i = 0; i < 3; i++) d[i] = e[i] - o[i];
    enu_basis(g->lat0_deg * DEG, g->lon0_deg * DEG, R);
    for (int i = 0; i < 3; i++) enu[i] = R[3 * i] * d[0] + R[3 * i + 1] * d[1] + R[3 * i + 2] * d[2];
    double c = cos(g->yaw_deg * DEG), s = sin(g->yaw_deg * DEG);
    xyz[0] = c * enu[0] + s * enu[1];
    xyz[1] = -s * enu[0] + c * enu[1];
    xyz[2] = enu[2];
}
