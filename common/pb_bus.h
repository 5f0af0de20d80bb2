/* pb_bus: the module shell's view of LCM, live or replayed.
 *
 * A module's shell subscribes handlers and publishes messages through a pb_bus_t.
 * Live, that is LCM on a UDP multicast URL. In replay (--replay IN --out OUT)
 * events of IN are delivered in log order as fast as the CPU allows, and every
 * publish is appended to OUT stamped with the log time of the event being
 * handled, so replaying a log gives the same OUT every time.
 *
 * Timers fire on message time in replay (before the first event at or past
 * their deadline) and on the wall clock live.
 *
 * Ownership: pb_bus_create_* returns a bus the caller frees with pb_bus_destroy.
 * A pb_msg_t passed to a handler is valid only during the call. */
#ifndef PB_BUS_H
#define PB_BUS_H

#include <stdint.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The project's default URL: multicast, ttl=0 (never leaves the machine), an 8 MB
 * socket receive buffer so that LiDAR sweeps (330-600 KB) are not dropped. */
#define PB_DEFAULT_LCM_URL "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"

/* --lcm-url if given, else $LCM_DEFAULT_URL, else PB_DEFAULT_LCM_URL. */
const char *pb_lcm_url(const char *cli_url);

typedef struct pb_bus pb_bus_t;

typedef struct {
    const char *channel;
    const uint8_t *data;
    int32_t len;
    int64_t recv_utime;     /* live: receive wall time; replay: the event's log timestamp */
} pb_msg_t;

typedef void (*pb_handler_fn)(const pb_msg_t *msg, void *user);
typedef void (*pb_timer_fn)(int64_t now_utime, void *user);
/* Called for every message delivered to a subscription (used by pb_status). */
typedef void (*pb_input_hook_fn)(const char *channel, int64_t recv_utime, void *user);

pb_bus_t *pb_bus_create_live(const char *url, pb_err_t *err);
pb_bus_t *pb_bus_create_replay(const char *in_path, const char *out_path, pb_err_t *err);
/* A replay bus whose input is not an LCM log but read by the shell itself (a
 * candump file, say): publishes go to out_path stamped with the time given to
 * pb_bus_advance. pb_bus_run is not used with it (it returns -1). */
pb_bus_t *pb_bus_create_source(const char *out_path, pb_err_t *err);
void pb_bus_destroy(pb_bus_t *bus);

int pb_bus_is_replay(const pb_bus_t *bus);

/* channel is an exact channel name (LCM's regex semantics live; exact match or
 * ".*" in replay). Live subscriptions get a 1000-deep queue. Returns 0 or -1. */
int pb_bus_subscribe(pb_bus_t *bus, const char *channel, pb_handler_fn fn, void *user);

/* Publishes encoded bytes. Returns 0 or -1 (err set). */
int pb_bus_publish(pb_bus_t *bus, const char *channel, const void *data, int32_t len, pb_err_t *err);

/* Encodes an lcm-gen'd message and publishes it:
 *   PB_PUBLISH(bus, "POSE", portobello_pose_t, &pose, &err) */
#define PB_PUBLISH(bus, channel, type, msgp, errp) \
    pb_bus_publish_encoded((bus), (channel), (const void *)(msgp), \
        (int (*)(const void *))type##_encoded_size, \
        (int (*)(void *, int, int, const void *))type##_encode, (errp))
int pb_bus_publish_encoded(pb_bus_t *bus, const char *channel, const void *msg,
                           int (*size_fn)(const void *),
                           int (*encode_fn)(void *, int, int, const void *), pb_err_t *err);

/* Calls fn every period_us (first call one period after the first event). Live, the
 * period is kept on CLOCK_MONOTONIC, so a wall-clock step does not stall the timer. */
int pb_bus_add_timer(pb_bus_t *bus, int64_t period_us, pb_timer_fn fn, void *user);

void pb_bus_set_input_hook(pb_bus_t *bus, pb_input_hook_fn fn, void *user);

/* Time of the event being handled (replay: log timestamp; live: wall clock). */
int64_t pb_bus_now(const pb_bus_t *bus);
/* A clock that never steps (replay: the log time; live: CLOCK_MONOTONIC), for measuring
 * intervals. Live timers run on it; their callbacks still get the wall time. */
int64_t pb_bus_monotonic(const pb_bus_t *bus);

/* Runs until pb_bus_stop, a signal (see pb_signal) or the end of the replay log.
 * Returns 0 on a clean end, -1 on error (a corrupt input log: err names the byte
 * offset; everything published before it is already in OUT). */
int pb_bus_run(pb_bus_t *bus, pb_err_t *err);
void pb_bus_stop(pb_bus_t *bus);

/* For shells with an input of their own (pb_bus_create_source, or a device read
 * beside a live bus): replay fires the timers due at or before t, then makes t
 * the bus time (call it with each input's time, in order); live fires the timers
 * due on the wall clock and ignores t. Returns -1 once a replay publish failed
 * (err set), else 0. */
int pb_bus_advance(pb_bus_t *bus, int64_t t, pb_err_t *err);

/* Replay only: events read and delivered so far. */
int64_t pb_bus_events_read(const pb_bus_t *bus);

#ifdef __cplusplus
}
#endif
#endif
