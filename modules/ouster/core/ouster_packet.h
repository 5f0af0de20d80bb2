/* ouster_packet: the byte layout of Ouster UDP lidar and IMU packets, per profile.
 *
 * Lidar packets (little-endian), per the Ouster sensor docs and ouster-sdk parsing.cpp:
 *  LEGACY: columns_per_packet columns of [16 B header: u64 timestamp ns, u16
 *    measurement_id, u16 frame_id, u32 encoder count][rows x 12 B pixels][u32 status,
 *    0xFFFFFFFF = valid]. Pixel: range bits 0-19 (mm), reflectivity byte 4, signal u16 @6,
 *    near-IR u16 @8.
 *  Others: [32 B packet header: u16 packet_type (1), u16 frame_id, 24-bit init_id,
 *    40-bit prod_sn, alert flags @12, thermal/shot-limiting countdowns @16/@17 and
 *    states @18/@19] + columns of [12 B header: u64 timestamp, u16 measurement_id,
 *    u16 status (bit 0 = valid)][rows x pixel] + [32 B footer].
 *    RNG19_RFL8_SIG16_NIR16 (12 B): range bits 0-18, refl @4, signal u16 @6, NIR u16 @8.
 *    ..._DUAL (16 B): range 0-18, refl @3, range2 bits 32-50, refl2 @7, signal @8,
 *      signal2 @10, NIR @12.
 *    RNG15_RFL8_NIR8 (4 B): range bits 0-14 in units of 8 mm, refl @2, NIR @3 x 16.
 * IMU LEGACY (48 B): u64 sys_ts, accel_ts, gyro_ts (ns); f32 accel x,y,z (g); f32 gyro
 *   x,y,z (deg/s).
 * Pure functions, no allocation. */
#ifndef OUSTER_PACKET_H
#define OUSTER_PACKET_H

#include <stddef.h>
#include <stdint.h>
#include "ouster_meta.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    ouster_profile_t profile;
    int rows, cols_per_packet;
    size_t packet_header, col_header, pixel_size, col_footer, packet_footer;
    size_t col_size, packet_size;
    int has_signal;             /* profile carries signal and near-IR */
} ouster_layout_t;

/* Layout of a profile for rows x cols_per_packet; returns 0, or -1 for an unknown profile. */
int ouster_layout_init(ouster_layout_t *L, ouster_profile_t profile, int rows, int cols_per_packet);

typedef struct {
    uint16_t packet_type, frame_id;
    uint32_t init_id;
    uint64_t prod_sn;
    uint8_t alert_flags, countdown_thermal_shutdown, countdown_shot_limiting, thermal_shutdown, shot_limiting;
} ouster_packet_header_t;

/* Non-legacy packet header (buf holds at least 32 bytes). */
void ouster_packet_header_decode(const uint8_t *buf, ouster_packet_header_t *h);

typedef struct {
    uint64_t timestamp_ns;
    uint16_t measurement_id, frame_id;  /* frame_id: the column's (LEGACY) or the packet's */
    int valid;                          /* column status says valid */
    const uint8_t *pixels;              /* rows x pixel_size bytes */
} ouster_column_t;

/* Column k of a packet of the layout's size (no bounds checks beyond that). */
void ouster_column_decode(const ouster_layout_t *L, const uint8_t *packet, int k, uint16_t packet_frame_id,
                          ouster_column_t *c);

/* Where a pixel's fields sit (byte offsets into the pixel) in the profiles whose range
 * is a 32-bit word; which_return 2 picks the second return of the DUAL profile.
 * range_mask 0: RNG15_RFL8_NIR8 (a packed 4-byte pixel) or an unknown profile. Inline,
 * so that a constant profile gives constant offsets. */
typedef struct {
    uint32_t range_mask;
    uint8_t range, reflectivity, signal, near_ir;
} ouster_pixel_fields_t;

static inline ouster_pixel_fields_t ouster_pixel_fields(ouster_profile_t profile, int which_return)
{
    const uint8_t second = which_return == 2;
    ouster_pixel_fields_t f = { 0, 0, 0, 0, 0 };
    if (profile == OUSTER_PROFILE_LEGACY || profile == OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16) {
        f.range_mask = profile == OUSTER_PROFILE_LEGACY ? 0xFFFFFu : 0x7FFFFu;
        f.reflectivity = 4; f.signal = 6; f.near_ir = 8;
    } else if (profile == OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL) {
        f.range_mask = 0x7FFFFu;
        f.range = (uint8_t)(4 * second); f.reflectivity = (uint8_t)(3 + 4 * second);
        f.signal = (uint8_t)(8 + 2 * second); f.near_ir = 12;
    }
    return f;
}

#define OUSTER_IMU_LEGACY_SIZE 48
#define OUSTER_G 9.80665   /* m/s^2 per g, as ouster-sdk converts */

typedef struct {
    uint64_t sys_ts_ns, accel_ts_ns, gyro_ts_ns;
    float accel_g[3], gyro_dps[3];
} ouster_imu_packet_t;

/* Returns 0, or -1 if len is not 48. Values are returned as sent (may be non-finite). */
int ouster_imu_decode(const uint8_t *buf, size_t len, ouster_imu_packet_t *imu);

static inline uint16_t ouster_rd16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static inline uint32_t ouster_rd32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline uint64_t ouster_rd64(const uint8_t *p) { return ouster_rd32(p) | (uint64_t)ouster_rd32(p + 4) << 32; }

#ifdef __cplusplus
}
#endif
#endif
