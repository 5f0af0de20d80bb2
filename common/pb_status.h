/* pb_status: the STATUS heartbeat of a module.
 *
 * Counts every message delivered by the bus per channel, keeps named counters
 * (rejected inputs by reason, ...) and the last error, and publishes a
 * portobello_status_t on channel STATUS every period (message time in replay);
 * live, the first one is published by pb_status_create itself.
 * Ownership: created on a bus, destroyed by the caller before the bus. */
#ifndef PB_STATUS_H
#define PB_STATUS_H

#include <stdint.h>
#include "pb_bus.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pb_status pb_status_t;

pb_status_t *pb_status_create(pb_bus_t *bus, const char *module, int64_t period_us);
void pb_status_destroy(pb_status_t *st);

/* Message time of the newest input, used for input ages and the STATUS utime.
 * Shells call it with each decoded message's utime. */
void pb_status_input_time(pb_status_t *st, const char *channel, int64_t msg_utime);
void pb_status_count(pb_status_t *st, const char *counter, int64_t increment);
int64_t pb_status_counter(const pb_status_t *st, const char *counter);
/* Sets last_error (and prints it to stderr once per distinct message). */
void pb_status_error(pb_status_t *st, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
void pb_status_set_state(pb_status_t *st, int8_t state);
/* Publishes one heartbeat now (also done by the timer). */
int pb_status_publish(pb_status_t *st);

#ifdef __cplusplus
}
#endif
#endif
