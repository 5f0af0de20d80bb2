/* pb_geo: the site's geo-reference, map frame <-> WGS84.
 *
 * The map frame is a local tangent plane at the origin (lat0, lon0, alt0 on the
 * WGS84 ellipsoid), with +x pointing yaw_deg counter-clockwise from east and z
 * up. Conversions go through ECEF exactly (no flat-earth approximation). */
#ifndef PB_GEO_H
#define PB_GEO_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    double lat0_deg, lon0_deg, alt0_m;  /* origin of map on the WGS84 ellipsoid */
    double yaw_deg;                     /* angle from east to map +x, CCW, degrees */
} pb_georef_t;

void pb_geo_map_to_wgs84(const pb_georef_t *g, const double xyz[3], double *lat_deg, double *lon_deg, double *alt_m);
void pb_geo_wgs84_to_map(const pb_georef_t *g, double lat_deg, double lon_deg, double alt_m, double xyz[3]);
/* Rotates a vector from map to ENU (east, north, up) at the origin. */
void pb_geo_map_to_enu_vec(const pb_georef_t *g, const double v_map[3], double v_enu[3]);

#ifdef __cplusplus
}
#endif
#endif
