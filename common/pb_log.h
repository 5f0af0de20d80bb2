/* pb_log: LCM event logs (the format lcm-logger writes), read strictly.
 *
 * lcm's own reader resynchronises silently over garbage; this one stops at the
 * first damaged byte and says where, so a replay never quietly skips data.
 * Writing goes through lcm's own lcm_eventlog.
 *
 * Ownership: pb_log_t is opaque, created by pb_log_open_read/_write and freed by
 * pb_log_close. An event returned by pb_log_next points into the reader's buffer
 * and is valid until the next call. */
#ifndef PB_LOG_H
#define PB_LOG_H

#include <stdint.h>
#include <stdlib.h>
#include "pb_err.h"
#include "pb_math.h"
#include "portobello_pose_t.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pb_log pb_log_t;

typedef struct {
    int64_t eventnum;
    int64_t timestamp;      /* us since epoch: receive time as logged */
    const char *channel;    /* NUL-terminated */
    const uint8_t *data;
    int32_t datalen;
    int64_t offset;         /* byte offset of this event's header in the file */
} pb_event_t;

pb_log_t *pb_log_open_read(const char *path, pb_err_t *err);
pb_log_t *pb_log_open_write(const char *path, pb_err_t *err);

/* Reads the next event. Returns 1 with *ev filled, 0 at the end of the file, -1 on a
 * corrupt event (err: "PATH: byte N: what"). A file that ends inside its last event
 * (a torn event: a recording cut by a power loss) ends there: 0, with a warning naming
 * the byte offset printed to stderr and kept for pb_log_torn. */
int pb_log_next(pb_log_t *log, pb_event_t *ev, pb_err_t *err);
/* A pose_t event (GROUND_TRUTH, POSE...): the message, and its pose (map <- the message's
 * frame) as a transform. Returns 0, or -1 if it does not decode (err: "byte N: CHANNEL
 * does not decode as pose_t"). */
int pb_log_pose(const pb_event_t *ev, portobello_pose_t *msg, pb_transform_t *pose, pb_err_t *err);
/* A log's poses and scans in one pass, in log order: pose(message, its transform, user)
 * for each pose_t on pose_channel, scan(event, user, err) for each event on scan_channel
 * (a NULL function: the channel is skipped). Returns 0, or -1 with err "PATH: ..." for a
 * log that does not open or is damaged, a pose that does not decode, or the err a scan
 * call returned -1 with. */
typedef void (*pb_log_pose_fn)(const portobello_pose_t *msg, const pb_transform_t *pose, void *user);
typedef int (*pb_log_event_fn)(const pb_event_t *ev, void *user, pb_err_t *err);
int pb_log_read_track(const char *path, const char *pose_channel, pb_log_pose_fn pose, const char *scan_channel,
                      pb_log_event_fn scan, void *user, pb_err_t *err);
/* The torn-event warning once pb_log_next met one, else NULL. */
const char *pb_log_torn(const pb_log_t *log);

/* Appends an event (eventnum is assigned in order). Returns 0 or -1. */
int pb_log_write(pb_log_t *log, int64_t timestamp, const char *channel,
                 const void *data, int32_t datalen, pb_err_t *err);

/* Bytes read so far and file size (for progress), or written so far. */
int64_t pb_log_position(const pb_log_t *log);
int64_t pb_log_size(const pb_log_t *log);

/* Hands what was written to the kernel (fflush, no fsync): a recorder calls it often so a
 * power loss costs at most the last moments. Returns 0 or -1. */
int pb_log_flush(pb_log_t *log, pb_err_t *err);

/* Flushes and closes; returns 0, or -1 if data could not be written. NULL is a no-op. */
int pb_log_close(pb_log_t *log, pb_err_t *err);

/* Writing lcm-gen'd messages straight to a log, for programs that write a drive
 * without a bus (simdrive, lab_vehicle offline): one growing encode buffer, and the
 * first write error sticks (later writes are skipped; check `failed`, report `err`).
 *   pb_log_out_t o = { .log = log };
 *   PB_LOG_WRITE_MSG(&o, "POSE", portobello_pose_t, &pose);   (stamped with pose.utime)
 *   free(o.buf); */
typedef struct {
    pb_log_t *log;
    uint8_t *buf;
    int cap;
    pb_err_t err;
    int failed;
} pb_log_out_t;

#define PB_LOG_WRITE_MSG(o, channel, type, msgp) do { \
        int n_ = type##_encoded_size(msgp); \
        if (n_ > (o)->cap) { (o)->cap = n_; (o)->buf = realloc((o)->buf, n_); } \
        type##_encode((o)->buf, 0, n_, msgp); \
        if (!(o)->failed && pb_log_write((o)->log, (msgp)->utime, channel, (o)->buf, n_, &(o)->err)) (o)->failed = 1; \
    } while (0)

#ifdef __cplusplus
}
#endif
#endif
