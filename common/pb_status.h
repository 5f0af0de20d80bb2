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
#include "pb_scan.h"

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
/* A message that does not decode: counted under COUNTER, and last_error
 * "CHANNEL: message of N bytes does not decode". */
void pb_status_undecodable(pb_status_t *st, const char *counter, const pb_msg_t *msg);
/* A handler's decoding of an lcm-gen'd message, its utime noted as the input's time; one
 * that does not decode is counted under COUNTER. 0, or -1 (the handler returns):
 *   if (PB_STATUS_DECODE(a->status, msg, portobello_pose_t, &p, "undecodable_pose")) return; */
#define PB_STATUS_DECODE(st, msg, type, out, counter) \
    (type##_decode((msg)->data, 0, (msg)->len, (out)) < 0 \
         ? (pb_status_undecodable((st), (counter), (msg)), -1) \
         : (pb_status_input_time((st), (msg)->channel, (out)->utime), 0))
/* Publishes one heartbeat now (also done by the timer). */
int pb_status_publish(pb_status_t *st);
/* pb_scan_points for a shell: what is wrong with the sweep goes to STATUS, not stderr
 * only: a sweep that is not consistent is counted (scan_invalid, -1 returned), NaN/inf
 * points of a point-form sweep, left out by pb_scan_points, are counted
 * (scan_nonfinite_points). Returns the number of points or -1. */
int pb_status_scan_points(pb_status_t *st, const portobello_lidar_scan_t *scan, pb_points_t *pts);
/* The last heartbeat of a run: state STOPPING, or with an error (the message that stopped
 * the run) state ERROR and last_error set, the message printed once as "MODULE: ERROR".
 * Returns what pb_status_publish returns. */
int pb_status_finish(pb_status_t *st, const char *error);

#ifdef __cplusplus
}

/* PB_STATUS_DECODE for C++ handlers, the message's use a function: decodes it with the
 * lcm-gen'd decode, notes its utime, calls use(message), frees it. 0, or -1 when it does
 * not decode (counted under counter). */
template <typename T, typename Use>
int pb_status_take(pb_status_t *st, const pb_msg_t *msg, int (*decode)(const void *, int, int, T *),
                   int (*cleanup)(T *), Use use, const char *counter = "undecodable")
{
    T m;
    if (decode(msg->data, 0, msg->len, &m) < 0) {
        pb_status_undecodable(st, counter, msg);
        return -1;
    }
    pb_status_input_time(st, msg->channel, m.utime);
    use(m);
    cleanup(&m);
    return 0;
}
#endif
#endif
