/* ouster_meta: an Ouster sensor's metadata JSON (what `GET /api/v1/sensor/metadata`
 * returns and what ouster-sdk saves next to a pcap), parsed with cJSON.
 *
 * Both layouts are read:
 *  - flat (FW 1.x-2.x "legacy" files): beam_altitude_angles, data_format, lidar_mode,
 *    lidar_to_sensor_transform, ... at the top level;
 *  - nested (FW 2.x-3.x): beam_intrinsics, lidar_data_format, config_params,
 *    lidar_intrinsics, imu_intrinsics, sensor_info.
 * Missing fields take the defaults ouster-sdk documents and uses (gen-1 OS1 values);
 * every default used is listed in ouster_meta_t.defaults. Beam angles have no default:
 * a file without them is refused (a made-up calibration would give silently wrong
 * points). Ownership: ouster_meta_t is a plain value, nothing to free. */
#ifndef OUSTER_META_H
#define OUSTER_META_H

#include <stddef.h>
#include <stdint.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

#define OUSTER_MAX_ROWS 256
#define OUSTER_MAX_COLS 4096
#define OUSTER_MAX_PACKET_COLS 64   /* columns per packet (sensors send 16) */

typedef enum {
    OUSTER_PROFILE_UNKNOWN = 0,
    OUSTER_PROFILE_LEGACY,
    OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16,
    OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL,
    OUSTER_PROFILE_RNG15_RFL8_NIR8,
} ouster_profile_t;

typedef struct {
    char prod_line[64];         /* "OS-1-64"; "" if absent */
    char prod_sn[32];
    char fw_rev[96];            /* build_rev */
    char lidar_mode[16];        /* "1024x10" */
    int rows;                   /* pixels_per_column */
    int cols_per_frame;         /* columns_per_frame */
    int cols_per_packet;        /* columns_per_packet */
    int column_window[2];       /* first, last measurement_id the sensor sends (inclusive) */
    int frame_rate_hz;          /* from lidar_mode, 10 if unknown */
    ouster_profile_t profile;   /* udp_profile_lidar */
    int imu_profile_legacy;     /* 1 if udp_profile_imu is LEGACY (or absent) */
    double beam_altitude_deg[OUSTER_MAX_ROWS];
    double beam_azimuth_deg[OUSTER_MAX_ROWS];
    int pixel_shift_by_row[OUSTER_MAX_ROWS];
    double lidar_origin_to_beam_origin_mm;
    double beam_to_lidar[16];   /* row-major, mm */
    double lidar_to_sensor[16]; /* row-major, mm */
    double imu_to_sensor[16];   /* row-major, mm */
    uint32_t init_id;           /* initialization_id, 0 if absent */
    uint64_t prod_sn_num;       /* prod_sn as a number, 0 if absent */
    int udp_port_lidar, udp_port_imu;  /* 0 if absent */
    char defaults[256];         /* comma-separated names of fields that took defaults */
} ouster_meta_t;

/* Parses metadata JSON text (len bytes, need not be NUL-terminated). Returns 0, or -1
 * with err naming the field ("beam_altitude_angles: 63 values, expected 64"). */
int ouster_meta_parse(const char *json, size_t len, ouster_meta_t *m, pb_err_t *err);
/* Reads and parses a file; errors are prefixed with the path. */
int ouster_meta_load(const char *path, ouster_meta_t *m, pb_err_t *err);

const char *ouster_profile_name(ouster_profile_t p);
ouster_profile_t ouster_profile_of_name(const char *name);

#ifdef __cplusplus
}
#endif
#endif
