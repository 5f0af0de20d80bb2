/* Simulated Toyota Prius powertrain CAN: 0x0AA WHEEL_SPEEDS and 0x0B4 SPEED, encoded
 * exactly as vehicles/dbc/toyota_prius_2017_pt_generated.dbc describes them. */
#ifndef SIM_CAN_H
#define SIM_CAN_H

#include <stdint.h>
#include "trajectory.h"
#include "pb_vehicle.h"

#define CAN_ID_WHEEL_SPEEDS 0x0AA
#define CAN_ID_SPEED 0x0B4
#define CAN_WHEEL_SPEEDS_PERIOD_US 12000
#define CAN_SPEED_PERIOD_US 24000

/* Ground-truth wheel speeds (km/h) from the rigid-body motion: each contact point
 * moves with v + omega x r (front wheels steer: their magnitude is what they see). */
void can_wheel_speeds_kmh(const pb_vehicle_t *v, const traj_state_t *st, double *fl, double *fr, double *rl, double *rr);
void can_encode_wheel_speeds(double fl, double fr, double rl, double rr, uint8_t out[8]);
void can_encode_speed(double kmh, uint8_t encoder, uint8_t out[8]);
/* Toyota checksum: id high byte + id low byte + length + data bytes 0..len-2. */
uint8_t can_toyota_checksum(uint32_t id, const uint8_t *data, int len);

#endif
