/* pb_clock_offset: the clock of a device that stamps its own messages (a GNSS receiver, the
 * participant's headset) against the car's sensors, from when its messages arrive among
 * theirs.
 *
 * A message arrives a little after the moment it stamps, so its stamp minus the newest time
 * of the other sensors when it arrives (its lag) lies within a few hundred milliseconds of 0
 * when both clocks agree. A median lag farther from 0 than tol_us is the device's clock
 * offset (a receiver on GPS time against sensors on UTC: 18 s; a headset never synchronised
 * with the car: anything), to be taken out of its stamps. The median is up to a sensor
 * period off the offset itself (where in that period the message arrives).
 *
 * Pure: no I/O, no clock. Ownership: pb_clock_offset_t is a plain value. */
#ifndef PB_CLOCK_OFFSET_H
#define PB_CLOCK_OFFSET_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* A device's clock this near the sensors' is no offset: a message's latency plus a sensor
 * period; 0.3 s at 15 m/s is 4.5 m along the path, within what GNSS errs, and a head a few
 * centimetres. The localizer, the mapper and the occlusion module use this. */
#define PB_CLOCK_OFFSET_TOL_US 300000

/* The rule on n lags (sorted in place): their median, or 0 when it lies within tol_us of 0
 * or n == 0. */
int64_t pb_clock_offset_median(int64_t *lags, size_t n, int64_t tol_us);

/* Live: the last PB_CLOCK_OFFSET_LAGS lags, the offset from PB_CLOCK_OFFSET_MIN of them on. */
enum { PB_CLOCK_OFFSET_LAGS = 5, PB_CLOCK_OFFSET_MIN = 3 };
typedef struct {
    int64_t tol_us;
    int64_t lag[PB_CLOCK_OFFSET_LAGS];
    int n, next;
    int64_t offset;      /* to take out of the device's stamps (0: none) */
    int64_t reported;    /* the offset the caller last said */
} pb_clock_offset_t;

void pb_clock_offset_init(pb_clock_offset_t *c, int64_t tol_us);
/* Forgets the lags (the sensors' clock stepped), keeps the offset until new lags say. */
void pb_clock_offset_forget(pb_clock_offset_t *c);
/* A message stamped `stamp` arrived when the sensors' newest time was `newest` (0: no sensor
 * yet; not counted). Returns 1 when the offset now differs from the one last reported by more
 * than tol_us (the caller says so and it becomes the reported one), else 0. */
int pb_clock_offset_add(pb_clock_offset_t *c, int64_t stamp, int64_t newest);

#ifdef __cplusplus
}
#endif

#endif
