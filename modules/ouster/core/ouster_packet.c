/* Ouster packet layouts; see ouster_packet.h for the byte positions. */
#include "ouster_packet.h"

#include <string.h>

int ouster_layout_init(ouster_layout_t *L, ouster_profile_t profile, int rows, int cols_per_packet)
{
    memset(L, 0, sizeof *L);
    L->profile = profile;
    L->rows = rows;
    L->cols_per_packet = cols_per_packet;
    switch (profile) {
    case OUSTER_PROFILE_LEGACY:
        L->col_header = 16; L->pixel_size = 12; L->col_footer = 4; L->has_signal = 1;
        break;
    case OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16:
        L->packet_header = 32; L->col_header = 12; L->pixel_size = 12; L->packet_footer = 32; L->has_signal = 1;
        break;
    case OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL:
        L->packet_header = 32; L->col_header = 12; L->pixel_size = 16; L->packet_footer = 32; L->has_signal = 1;
        break;
    case OUSTER_PROFILE_RNG15_RFL8_NIR8:
        L->packet_header = 32; L->col_header = 12; L->pixel_size = 4; L->packet_footer = 32; L->has_signal = 0;
        break;
    default:
        return -1;
    }
    L->col_size = L->col_header + (size_t)rows * L->pixel_size + L->col_footer;
    L->packet_size = L->packet_header + (size_t)cols_per_packet * L->col_size + L->packet_footer;
    return 0;
}

void ouster_packet_header_decode(const uint8_t *b, ouster_packet_header_t *h)
{
    h->packet_type = ouster_rd16(b);
    h->frame_id = ouster_rd16(b + 2);
    h->init_id = (uint32_t)b[4] | (uint32_t)b[5] << 8 | (uint32_t)b[6] << 16;
    h->prod_sn = 0;
    for (int i = 4; i >= 0; i--) h->prod_sn = h->prod_sn << 8 | b[7 + i];
    h->alert_flags = b[12];
    h->countdown_thermal_shutdown = b[16];
    h->countdown_shot_limiting = b[17];
    h->thermal_shutdown = b[18] & 0x0f;
    h->shot_limiting = b[19] & 0x0f;
}

void ouster_column_decode(const ouster_layout_t *L, const uint8_t *packet, int k, uint16_t packet_frame_id,
                          ouster_column_t *c)
{
    const uint8_t *col = packet + L->packet_header + (size_t)k * L->col_size;
    c->timestamp_ns = ouster_rd64(col);
    c->measurement_id = ouster_rd16(col + 8);
    c->pixels = col + L->col_header;
    if (L->profile == OUSTER_PROFILE_LEGACY) {
        c->frame_id = ouster_rd16(col + 10);
        c->valid = ouster_rd32(col + L->col_size - 4) == 0xFFFFFFFFu;
    } else {
        c->frame_id = packet_frame_id;
        c->valid = ouster_rd16(col + 10) & 1;
    }
}

int ouster_imu_decode(const uint8_t *b, size_t len, ouster_imu_packet_t *imu)
{
    if (len != OUSTER_IMU_LEGACY_SIZE) return -1;
    imu->sys_ts_ns = ouster_rd64(b);
    imu->accel_ts_ns = ouster_rd64(b + 8);
    imu->gyro_ts_ns = ouster_rd64(b + 16);
    for (int i = 0; i < 3; i++) {
        uint32_t a = ouster_rd32(b + 24 + 4 * i), g = ouster_rd32(b + 36 + 4 * i);
        memcpy(&imu->accel_g[i], &a, 4);
        memcpy(&imu->gyro_dps[i], &g, 4);
    }
    return 0;
}
