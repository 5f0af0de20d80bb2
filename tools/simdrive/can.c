/* CAN: signal encoding per the Prius DBC (Motorola byte order, big-endian). */
#include "can.h"

#include <math.h>
#include <string.h>

static void put_be16(uint8_t *p, long raw)
{
    if (raw < 0) raw = 0;
    if (raw > 0xFFFF) raw = 0xFFFF;
    p[0] = (uint8_t)(raw >> 8);
    p[1] = (uint8_t)raw;
}

void can_wheel_speeds_kmh(const pb_vehicle_t *v, const traj_state_t *st, double *fl, double *fr, double *rl, double *rr)
{
    /* base frame: origin velocity (v, 0) (no side slip at the rear axle), omega about z */
    const double w = st->omega, L = v->wheelbase, hf = v->track_front / 2, hr = v->track_rear / 2;
    /* point (x, y): velocity (v - w y, w x) */
    *fl = hypot(st->v - w * hf, w * L) * 3.6;
    *fr = hypot(st->v + w * hf, w * L) * 3.6;
    *rl = fabs(st->v - w * hr) * 3.6;
    *rr = fabs(st->v + w * hr) * 3.6;
}

void can_encode_wheel_speeds(double fl, double fr, double rl, double rr, uint8_t out[8])
{
    /* WHEEL_SPEED_xx: 16 bits @0+ (0.01, -67.67): raw = (kmh + 67.67) / 0.01.
     * Start bits 7, 23, 39, 55 (Motorola MSB) = bytes 0, 2, 4, 6, in the order FR, FL, RR, RL. */
    put_be16(out + 0, lround((fr + 67.67) / 0.01));
    put_be16(out + 2, lround((fl + 67.67) / 0.01));
    put_be16(out + 4, lround((rr + 67.67) / 0.01));
    put_be16(out + 6, lround((rl + 67.67) / 0.01));
}

uint8_t can_toyota_checksum(uint32_t id, const uint8_t *data, int len)
{
    unsigned sum = ((id >> 8) & 0xFF) + (id & 0xFF) + (unsigned)len;
    for (int i = 0; i < len - 1; i++) sum += data[i];
    return (uint8_t)(sum & 0xFF);
}

void can_encode_speed(double kmh, uint8_t encoder, uint8_t out[8])
{
    /* ENCODER 39|8 = byte 4; SPEED 47|16 (0.01 km/h) = bytes 5-6; CHECKSUM 63|8 = byte 7 */
    memset(out, 0, 8);
    out[4] = encoder;
    put_be16(out + 5, lround(kmh / 0.01));
    out[7] = can_toyota_checksum(CAN_ID_SPEED, out, 8);
}

void can_encode_gear(int gear, uint8_t out[8])
{
    /* GEAR 13|6@0+ = bits 5..0 of byte 1; DRIVE_ENGAGED 47|1@0+ = bit 7 of byte 5 */
    memset(out, 0, 8);
    out[1] = (uint8_t)(gear & 0x3F);
    if (gear == CAN_GEAR_D) out[5] = 0x80;
}
