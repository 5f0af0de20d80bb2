/* Simulated Toyota Prius powertrain CAN: 0x0AA WHEEL_SPEEDS, 0x0B4 SPEED and 0x3BC
 * GEAR_PACKET, encoded exactly as vehicles/dbc/toyota_prius_2017_pt_generated.dbc
 * describes them. Speeds are magnitudes (reversing shows only in the gear). */
#ifndef SIM_CAN_H
#define SIM_CAN_H

#include <stdint.h>
#include "trajectory.h"
#include "pb_vehicle.h"

#define CAN_ID_WHEEL_SPEEDS 0x0AA
#define CAN_ID_SPEED 0x0B4
#define CAN_WHEEL_SPEEDS_PERIOD_US 12000
#define CAN_SPEED_PERIOD_US 24000
#define CAN_ID_GEAR 0x3BC
#define CAN_GEAR_PERIOD_US 1000000   /* and at every shift (the real RAV4: about 1 Hz) */
#define CAN_GEAR_TICK_US 20000       /* how soon a shift is sent */
/* GEAR_PACKET.GEAR values (the DBC's VAL_ table) */
#define CAN_GEAR_D 0
#define CAN_GEAR_R 16

/* Ground-truth wheel speeds (km/h) from the rigid-body motion: each contact point
 * moves with v + omega x r (front wheels steer: their magnitude is what they see). */
void can_wheel_speeds_kmh(const pb_vehicle_t *v, const traj_state_t *st, double *fl, double *fr, double *rl, double *rr);
void can_encode_wheel_speeds(double fl, double fr, double rl, double rr, uint8_t out[8]);
void can_encode_speed(double kmh, uint8_t encoder, uint8_t out[8]);
/* GEAR_PACKET: GEAR (CAN_GEAR_*), DRIVE_ENGAGED set in D (as the RAV4 log shows). */
void can_encode_gear(int gear, uint8_t out[8]);
/* Toyota checksum: id high byte + id low byte + length + data bytes 0..len-2. */
uint8_t can_toyota_checksum(uint32_t id, const uint8_t *data, int len);

#endif
