/* pb_log: events round-trip; a torn last event ends the log with a warning naming its byte
 * offset (the data before it is kept); corruption is an error with the byte offset. */
#include <stdint.h>
#include <stdlib.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_log.h"

static int64_t file_size(const char *p)
{
    FILE *f = fopen(p, "rb");
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fclose(f);
    return n;
}

/* Reads all events; returns the count, sets *rc to the last pb_log_next result. */
static int read_all(const char *path, int *rc, pb_err_t *err, int64_t *last_ts)
{
    pb_log_t *log = pb_log_open_read(path, err);
    if (!log) { *rc = -2; return 0; }
    pb_event_t ev;
    int n = 0;
    while ((*rc = pb_log_next(log, &ev, err)) == 1) {
        n++;
        if (last_ts) *last_ts = ev.timestamp;
    }
    pb_log_close(log, NULL);
    return n;
}

int main(void)
{
    char path[] = "/tmp/pb_test_log_XXXXXX";
    int fd = mkstemp(path);
    close(fd);
    pb_err_t err;

    /* Write 100 events of growing size on two channels. */
    pb_log_t *w = pb_log_open_write(path, &err);
    CHECK(w != NULL);
    uint8_t buf[1000];
    int64_t offsets[101];
    for (int i = 0; i < 100; i++) {
        for (int j = 0; j < i * 10; j++) buf[j] = (uint8_t)(i + j);
        offsets[i] = pb_log_position(w);
        CHECK(pb_log_write(w, 1000000 + i * 1000, i % 2 ? "ODD" : "EVEN", buf, i * 10, &err) == 0);
    }
    offsets[100] = pb_log_position(w);
    CHECK(pb_log_close(w, &err) == 0);
    CHECK(file_size(path) == offsets[100]);

    /* Read back exactly. */
    pb_log_t *r = pb_log_open_read(path, &err);
    pb_event_t ev;
    int n = 0, bad = 0;
    while (pb_log_next(r, &ev, &err) == 1) {
        if (ev.timestamp != 1000000 + n * 1000 || ev.datalen != n * 10 || ev.offset != offsets[n] ||
            strcmp(ev.channel, n % 2 ? "ODD" : "EVEN") != 0)
            bad++;
        for (int j = 0; j < ev.datalen; j++) if (ev.data[j] != (uint8_t)(n + j)) bad++;
        n++;
    }
    pb_log_close(r, NULL);
    CHECK(n == 100);
    CHECK(bad == 0);

    /* Cut in the middle of event 50's data (a recording cut by a power loss): 50 good events,
     * then a clean end with a warning naming the torn event's offset. */
    char cmd[1024], tpath[300], msg[128];
    snprintf(tpath, sizeof tpath, "%s.trunc", path);
    snprintf(cmd, sizeof cmd, "head -c %lld %s > %s", (long long)(offsets[50] + 40), path, tpath);
    CHECK(system(cmd) == 0);
    int rc;
    pb_log_t *t = pb_log_open_read(tpath, &err);
    pb_event_t tev;
    n = 0;
    while ((rc = pb_log_next(t, &tev, &err)) == 1) n++;
    CHECK(n == 50);
    CHECK(rc == 0);
    snprintf(msg, sizeof msg, "byte %lld: warning: the last event is torn", (long long)offsets[50]);
    CHECK(pb_log_torn(t) != NULL);
    if (pb_log_torn(t)) CHECK_CONTAINS(pb_log_torn(t), msg);
    CHECK(pb_log_next(t, &tev, &err) == 0);     /* and stays at the end */
    pb_log_close(t, NULL);

    /* Cut inside a header: the same. */
    snprintf(cmd, sizeof cmd, "head -c %lld %s > %s", (long long)(offsets[10] + 5), path, tpath);
    CHECK(system(cmd) == 0);
    n = read_all(tpath, &rc, &err, NULL);
    CHECK(n == 10 && rc == 0);

    /* A corrupted sync word at event 70. */
    snprintf(cmd, sizeof cmd, "cp %s %s && printf 'XXXX' | dd of=%s bs=1 seek=%lld conv=notrunc status=none",
             path, tpath, tpath, (long long)offsets[70]);
    CHECK(system(cmd) == 0);
    n = read_all(tpath, &rc, &err, NULL);
    CHECK(n == 70 && rc == -1);
    snprintf(msg, sizeof msg, "byte %lld: bad sync word", (long long)offsets[70]);
    CHECK_CONTAINS(err.msg, msg);

    /* A data length that runs past the end of the file. */
    snprintf(cmd, sizeof cmd, "cp %s %s && printf '\\x7f' | dd of=%s bs=1 seek=%lld conv=notrunc status=none",
             path, tpath, tpath, (long long)offsets[99] + 24);
    CHECK(system(cmd) == 0);
    n = read_all(tpath, &rc, &err, NULL);
    CHECK(n == 99 && rc == -1);     /* beyond any event's size: corrupt, not torn */

    /* Empty file: clean end, no events. */
    snprintf(cmd, sizeof cmd, ": > %s", tpath);
    CHECK(system(cmd) == 0);
    n = read_all(tpath, &rc, &err, NULL);
    CHECK(n == 0 && rc == 0);

    /* A pose_t event: message and transform; one that does not decode names channel and byte. */
    portobello_pose_t pose = {0};
    pose.utime = 42;
    pose.position[0] = 1.5; pose.position[2] = -2;
    pose.orientation[0] = 0.5; pose.orientation[3] = 0.25;
    uint8_t pbuf[1024];
    int plen = portobello_pose_t_encode(pbuf, 0, sizeof pbuf, &pose);
    CHECK(plen > 0);
    pb_event_t pev = { .channel = "GROUND_TRUTH", .data = pbuf, .datalen = plen, .offset = 4096 };
    portobello_pose_t got;
    pb_transform_t T;
    CHECK(pb_log_pose(&pev, &got, &T, &err) == 0);
    CHECK(got.utime == 42 && T.t[0] == 1.5 && T.t[1] == 0 && T.t[2] == -2);
    CHECK(T.q[0] == 0.5 && T.q[1] == 0 && T.q[3] == 0.25);
    pev.datalen = plen - 1;
    CHECK(pb_log_pose(&pev, &got, &T, &err) == -1);
    CHECK_CONTAINS(err.msg, "byte 4096: GROUND_TRUTH does not decode as pose_t");

    CHECK(pb_log_open_read("/nonexistent/x.lcm", &err) == NULL);
    CHECK_CONTAINS(err.msg, "/nonexistent/x.lcm: cannot open");
    CHECK(pb_log_open_write("/nonexistent/dir/x.lcm", &err) == NULL);
    CHECK_CONTAINS(err.msg, "/nonexistent/dir/x.lcm: cannot create");

    unlink(path);
    unlink(tpath);
    return pb_check_report("test_log");
}
