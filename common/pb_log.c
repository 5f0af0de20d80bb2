/* Strict reader and lcm_eventlog-backed writer for LCM event logs.
 * On-disk event: u32 sync 0xEDA1DA01, i64 eventnum, i64 timestamp,
 * i32 channel length, i32 data length, channel bytes, data bytes (big-endian). */
#include "pb_log.h"

#include <errno.h>
#include <lcm/eventlog.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define PB_LOG_SYNC 0xEDA1DA01u
#define PB_LOG_MAX_CHANNEL 255
#define PB_LOG_MAX_DATA (512 * 1024 * 1024)

struct pb_log {
    char path[512];
    int writing;
    FILE *f;                    /* reading */
    lcm_eventlog_t *out;        /* writing */
    int64_t pos, size, eventnum;
    uint8_t *buf;
    size_t cap;
    char channel[PB_LOG_MAX_CHANNEL + 1];
    char torn[700];             /* the warning about a torn last event; "" if none */
};

static uint32_t be32(const uint8_t *p) { return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3]; }
static uint64_t be64(const uint8_t *p) { return ((uint64_t)be32(p) << 32) | be32(p + 4); }

pb_log_t *pb_log_open_read(const char *path, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) { pb_err_set(err, "%s: cannot open: %s", path, strerror(errno)); return NULL; }
    pb_log_t *log = calloc(1, sizeof *log);
    snprintf(log->path, sizeof log->path, "%s", path);
    log->f = f;
    struct stat st;
    /* a pipe or FIFO has no size: read it to its end */
    log->size = fstat(fileno(f), &st) == 0 && S_ISREG(st.st_mode) ? (int64_t)st.st_size : -1;
    return log;
}

pb_log_t *pb_log_open_write(const char *path, pb_err_t *err)
{
    /* Refuse to open something that is not a writable file before lcm truncates it. */
    FILE *probe = fopen(path, "wb");
    if (!probe) { pb_err_set(err, "%s: cannot create: %s", path, strerror(errno)); return NULL; }
    fclose(probe);
    lcm_eventlog_t *out = lcm_eventlog_create(path, "w");
    if (!out) { pb_err_set(err, "%s: cannot create event log", path); return NULL; }
    pb_log_t *log = calloc(1, sizeof *log);
    snprintf(log->path, sizeof log->path, "%s", path);
    log->writing = 1;
    log->out = out;
    return log;
}

/* The file ends inside its last event: what lcm-logger leaves when the power goes
 * (or it is killed) mid-write. Everything before is the study's data, so this is
 * the end of the log, with a warning naming the byte offset, not an error. */
static int torn_end(pb_log_t *log, int64_t at, int64_t have, int64_t need)
{
    char got[64] = "";
    if (have >= 0) snprintf(got, sizeof got, " (%lld of its %lld bytes)", (long long)have, (long long)need);
    snprintf(log->torn, sizeof log->torn,
             "%s: byte %lld: warning: the last event is torn%s, as when a recording is cut short; "
             "the log is read up to byte %lld", log->path, (long long)at, got, (long long)at);
    fprintf(stderr, "%s\n", log->torn);
    fseek(log->f, 0, SEEK_END);
    log->pos = at;
    return 0;
}

const char *pb_log_torn(const pb_log_t *log) { return log && log->torn[0] ? log->torn : NULL; }

int pb_log_pose(const pb_event_t *ev, portobello_pose_t *msg, pb_transform_t *pose, pb_err_t *err)
{
    if (portobello_pose_t_decode(ev->data, 0, ev->datalen, msg) < 0)
        return pb_err_set(err, "byte %lld: %s does not decode as pose_t", (long long)ev->offset, ev->channel);
    memcpy(pose->t, msg->position, sizeof pose->t);
    memcpy(pose->q, msg->orientation, sizeof pose->q);
    return 0;
}

int pb_log_read_track(const char *path, const char *pose_channel, pb_log_pose_fn pose, const char *scan_channel,
                      pb_log_event_fn scan, void *user, pb_err_t *err)
{
    pb_log_t *log = pb_log_open_read(path, err);
    if (!log) return -1;
    pb_event_t ev;
    int rc;
    while ((rc = pb_log_next(log, &ev, err)) == 1) {
        if (pose && strcmp(ev.channel, pose_channel) == 0) {
            portobello_pose_t msg;
            pb_transform_t T;
            if (pb_log_pose(&ev, &msg, &T, err)) break;
            pose(&msg, &T, user);
        } else if (scan && strcmp(ev.channel, scan_channel) == 0 && scan(&ev, user, err)) {
            break;
        }
    }
    pb_log_close(log, NULL);
    if (rc == 1) pb_err_prefix(err, "%s", path);   /* stopped at a pose or a scan */
    return rc < 0 || rc == 1 ? -1 : 0;
}

int pb_log_next(pb_log_t *log, pb_event_t *ev, pb_err_t *err)
{
    if (log && log->torn[0]) return 0;
    if (!log || log->writing) return pb_err_set(err, "pb_log_next: not a log opened for reading");
    uint8_t hdr[28];
    int64_t at = log->pos;
    size_t got = fread(hdr, 1, sizeof hdr, log->f);
    if (got == 0 && feof(log->f)) return 0;
    if (got >= 4 && be32(hdr) != PB_LOG_SYNC)
        return pb_err_set(err, "%s: byte %lld: bad sync word 0x%08x (expected 0xEDA1DA01): corrupt log",
                          log->path, (long long)at, be32(hdr));
    if (got < sizeof hdr) return torn_end(log, at, got, 28);
    int64_t eventnum = (int64_t)be64(hdr + 4);
    int64_t timestamp = (int64_t)be64(hdr + 12);
    int32_t chlen = (int32_t)be32(hdr + 20);
    int32_t datalen = (int32_t)be32(hdr + 24);
    if (chlen <= 0 || chlen > PB_LOG_MAX_CHANNEL)
        return pb_err_set(err, "%s: byte %lld: channel length %d out of range 1..%d: corrupt log",
                          log->path, (long long)at, chlen, PB_LOG_MAX_CHANNEL);
    if (datalen < 0 || datalen > PB_LOG_MAX_DATA)
        return pb_err_set(err, "%s: byte %lld: data length %d out of range: corrupt log", log->path, (long long)at, datalen);
    if (log->size >= 0 && at + 28 + chlen + (int64_t)datalen > log->size)
        return torn_end(log, at, log->size - at, 28 + chlen + (int64_t)datalen);
    if (fread(log->channel, 1, (size_t)chlen, log->f) != (size_t)chlen)
        return torn_end(log, at, -1, 28 + chlen + (int64_t)datalen);
    log->channel[chlen] = 0;
    for (int i = 0; i < chlen; i++) {
        unsigned char c = (unsigned char)log->channel[i];
        if (c < 0x20 || c > 0x7e)
            return pb_err_set(err, "%s: byte %lld: channel name has byte 0x%02x: corrupt log", log->path, (long long)at, c);
    }
    if ((size_t)datalen > log->cap) {
        size_t cap = (size_t)datalen + 4096;
        uint8_t *nb = realloc(log->buf, cap);
        if (!nb) return pb_err_set(err, "%s: byte %lld: out of memory for %d bytes", log->path, (long long)at, datalen);
        log->buf = nb;
        log->cap = cap;
    }
    if (datalen && fread(log->buf, 1, (size_t)datalen, log->f) != (size_t)datalen)
        return torn_end(log, at, -1, 28 + chlen + (int64_t)datalen);
    log->pos = at + 28 + chlen + datalen;
    ev->eventnum = eventnum;
    ev->timestamp = timestamp;
    ev->channel = log->channel;
    ev->data = log->buf;
    ev->datalen = datalen;
    ev->offset = at;
    return 1;
}

int pb_log_write(pb_log_t *log, int64_t timestamp, const char *channel, const void *data, int32_t datalen, pb_err_t *err)
{
    if (!log || !log->writing) return pb_err_set(err, "pb_log_write: not a log opened for writing");
    size_t chlen = strlen(channel);
    if (chlen == 0 || chlen > PB_LOG_MAX_CHANNEL)
        return pb_err_set(err, "%s: channel name '%s' must be 1..%d characters", log->path, channel, PB_LOG_MAX_CHANNEL);
    lcm_eventlog_event_t le = {
        .eventnum = log->eventnum,
        .timestamp = timestamp,
        .channellen = (int32_t)chlen,
        .datalen = datalen,
        .channel = (char *)channel,
        .data = (void *)data,
    };
    if (lcm_eventlog_write_event(log->out, &le) != 0)
        return pb_err_set(err, "%s: write failed at event %lld: %s", log->path, (long long)log->eventnum, strerror(errno));
    log->eventnum++;
    log->pos += 28 + (int64_t)chlen + datalen;
    return 0;
}

int64_t pb_log_position(const pb_log_t *log) { return log ? log->pos : 0; }
int64_t pb_log_size(const pb_log_t *log) { return log ? log->size : 0; }

int pb_log_flush(pb_log_t *log, pb_err_t *err)
{
    if (!log || !log->writing) return 0;
    if (fflush(log->out->f) != 0) return pb_err_set(err, "%s: flush failed: %s", log->path, strerror(errno));
    return 0;
}

int pb_log_close(pb_log_t *log, pb_err_t *err)
{
    if (!log) return 0;
    int rc = 0;
    if (log->writing) {
        if (fflush(log->out->f) != 0) rc = pb_err_set(err, "%s: flush failed: %s", log->path, strerror(errno));
        lcm_eventlog_destroy(log->out);
    } else {
        fclose(log->f);
    }
    free(log->buf);
    free(log);
    return rc;
}
