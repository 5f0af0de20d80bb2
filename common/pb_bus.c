/* pb_bus: live LCM or replay of an event log, behind one small interface. */
#include "pb_bus.h"

#include <errno.h>
#include <lcm/lcm.h>
#include <regex.h>
#include <stdio.h>
#include <stdlib.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <string.h>
#include <time.h>

#include "pb_clock.h"
#include "pb_log.h"
#include "pb_signal.h"

#define PB_MAX_SUBS 64
#define PB_MAX_TIMERS 16
#define PB_LIVE_QUEUE 1000

typedef struct {
    pb_bus_t *bus;
    char *channel;
    regex_t re;
    pb_handler_fn fn;
    void *user;
    lcm_subscription_t *live;
} pb_sub_t;

typedef struct {
    int64_t period, next;
    pb_timer_fn fn;
    void *user;
} pb_timer_t;

struct pb_bus {
    int replay;
    lcm_t *lcm;
    pb_log_t *in, *out;
    pb_sub_t subs[PB_MAX_SUBS];
    int nsubs;
    pb_timer_t timers[PB_MAX_TIMERS];
    int ntimers;
    pb_input_hook_fn hook;
    void *hook_user;
    int64_t now;
    int64_t wall_off;         /* live: wall minus monotonic time, as timer callbacks see it */
    int wall_off_set;
    int64_t events;
    volatile int stop;
    pb_err_t publish_err;
    int publish_failed;
};

const char *pb_lcm_url(const char *cli_url)
{
    if (cli_url && *cli_url) return cli_url;
    const char *env = getenv("LCM_DEFAULT_URL");
    if (env && *env) return env;
    return PB_DEFAULT_LCM_URL;
}

pb_bus_t *pb_bus_create_live(const char *url, pb_err_t *err)
{
#ifdef __GLIBC__
    /* A live module receives large messages (a LiDAR sweep is ~330 KB), and a burst queues
     * several at once. glibc raises its mmap threshold after the first large free, after
     * which such buffers come from the heap and a burst's peak stays resident for good
     * (bench-bus: a small module's RSS stepped up 10% after one scheduling hiccup). A fixed
     * threshold keeps large buffers in mmap: freed, they go back to the system. */
    mallopt(M_MMAP_THRESHOLD, 128 * 1024);
#endif
    url = pb_lcm_url(url);
    lcm_t *lcm = lcm_create(url);
    if (!lcm) { pb_err_set(err, "cannot open LCM at '%s' (is there a multicast route? see README)", url); return NULL; }
    pb_bus_t *bus = calloc(1, sizeof *bus);
    bus->lcm = lcm;
    return bus;
}

pb_bus_t *pb_bus_create_replay(const char *in_path, const char *out_path, pb_err_t *err)
{
    if (!in_path || !out_path) { pb_err_set(err, "replay needs both --replay IN.lcm and --out OUT.lcm"); return NULL; }
    pb_log_t *in = pb_log_open_read(in_path, err);
    if (!in) return NULL;
    pb_log_t *out = pb_log_open_write(out_path, err);
    if (!out) { pb_log_close(in, NULL); return NULL; }
    pb_bus_t *bus = calloc(1, sizeof *bus);
    bus->replay = 1;
    bus->in = in;
    bus->out = out;
    return bus;
}

pb_bus_t *pb_bus_create_source(const char *out_path, pb_err_t *err)
{
    if (!out_path) { pb_err_set(err, "a source bus needs an output log (--out OUT.lcm)"); return NULL; }
    pb_log_t *out = pb_log_open_write(out_path, err);
    if (!out) return NULL;
    pb_bus_t *bus = calloc(1, sizeof *bus);
    bus->replay = 1;
    bus->out = out;
    return bus;
}

void pb_bus_destroy(pb_bus_t *bus)
{
    if (!bus) return;
    for (int i = 0; i < bus->nsubs; i++) {
        if (bus->subs[i].live) lcm_unsubscribe(bus->lcm, bus->subs[i].live);
        regfree(&bus->subs[i].re);
        free(bus->subs[i].channel);
    }
    if (bus->lcm) lcm_destroy(bus->lcm);
    pb_log_close(bus->in, NULL);
    pb_err_t e;
    if (pb_log_close(bus->out, &e) != 0) fprintf(stderr, "%s\n", e.msg);
    free(bus);
}

int pb_bus_is_replay(const pb_bus_t *bus) { return bus->replay; }
int64_t pb_bus_now(const pb_bus_t *bus) { return bus->replay ? bus->now : pb_clock_wall_utime(); }
int64_t pb_bus_monotonic(const pb_bus_t *bus) { return bus->replay ? bus->now : pb_clock_monotonic_utime(); }
int64_t pb_bus_events_read(const pb_bus_t *bus) { return bus->events; }
void pb_bus_stop(pb_bus_t *bus) { bus->stop = 1; }

void pb_bus_set_input_hook(pb_bus_t *bus, pb_input_hook_fn fn, void *user)
{
    bus->hook = fn;
    bus->hook_user = user;
}

static void deliver(pb_sub_t *s, const pb_msg_t *m)
{
    if (s->bus->hook) s->bus->hook(m->channel, m->recv_utime, s->bus->hook_user);
    s->fn(m, s->user);
}

static void live_trampoline(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    pb_sub_t *s = user;
    pb_msg_t m = { channel, rbuf->data, (int32_t)rbuf->data_size, rbuf->recv_utime };
    deliver(s, &m);
}

int pb_bus_subscribe(pb_bus_t *bus, const char *channel, pb_handler_fn fn, void *user)
{
    if (bus->nsubs >= PB_MAX_SUBS) return -1;
    pb_sub_t *s = &bus->subs[bus->nsubs];
    /* LCM matches channel names as anchored regular expressions; do the same in replay. */
    char pattern[600];
    snprintf(pattern, sizeof pattern, "^(%s)$", channel);
    if (regcomp(&s->re, pattern, REG_EXTENDED | REG_NOSUB) != 0) return -1;
    s->bus = bus;
    s->channel = strdup(channel);
    s->fn = fn;
    s->user = user;
    if (!bus->replay) {
        s->live = lcm_subscribe(bus->lcm, channel, live_trampoline, s);
        if (!s->live) { regfree(&s->re); free(s->channel); return -1; }
        /* LCM's default 30-deep queue silently drops bursts. */
        lcm_subscription_set_queue_capacity(s->live, PB_LIVE_QUEUE);
    }
    bus->nsubs++;
    return 0;
}

int pb_bus_publish(pb_bus_t *bus, const char *channel, const void *data, int32_t len, pb_err_t *err)
{
    if (bus->replay) {
        pb_err_t e;
        if (pb_log_write(bus->out, bus->now, channel, data, len, &e) != 0) {
            if (!bus->publish_failed) { bus->publish_err = e; bus->publish_failed = 1; }
            bus->stop = 1;
            if (err) *err = e;
            return -1;
        }
        return 0;
    }
    if (lcm_publish(bus->lcm, channel, data, (unsigned)len) != 0)
        return pb_err_set(err, "%s: lcm_publish of %d bytes failed", channel, len);
    return 0;
}

int pb_bus_publish_encoded(pb_bus_t *bus, const char *channel, const void *msg, int (*size_fn)(const void *),
                           int (*encode_fn)(void *, int, int, const void *), pb_err_t *err)
{
    int size = size_fn(msg);
    if (size < 0) return pb_err_set(err, "%s: cannot size message", channel);
    uint8_t stackbuf[4096];
    uint8_t *buf = size <= (int)sizeof stackbuf ? stackbuf : malloc((size_t)size);
    if (!buf) return pb_err_set(err, "%s: out of memory for %d bytes", channel, size);
    int rc;
    if (encode_fn(buf, 0, size, msg) != size)
        rc = pb_err_set(err, "%s: cannot encode message (an array length does not match its count?)", channel);
    else
        rc = pb_bus_publish(bus, channel, buf, size, err);
    if (buf != stackbuf) free(buf);
    return rc;
}

int pb_bus_add_timer(pb_bus_t *bus, int64_t period_us, pb_timer_fn fn, void *user)
{
    if (bus->ntimers >= PB_MAX_TIMERS || period_us <= 0) return -1;
    bus->timers[bus->ntimers++] = (pb_timer_t){ period_us, 0, fn, user };
    return 0;
}

/* Fires every timer whose deadline is at or before t, in deadline order. */
/* Live, t and the deadlines are monotonic; callbacks get wall time, which messages carry,
 * as deadline + (wall - monotonic). The offset is kept while it holds (within 50 ms), so a
 * periodic timer's times stay on an exact grid; a wall-clock step moves it at once. */
static int64_t wall_offset(pb_bus_t *bus, int64_t t)
{
    int64_t off = pb_clock_wall_utime() - t;
    if (!bus->wall_off_set || llabs(off - bus->wall_off) > 50000) {
        bus->wall_off = off;
        bus->wall_off_set = 1;
    }
    return bus->wall_off;
}

static void fire_timers(pb_bus_t *bus, int64_t t)
{
    for (;;) {
        pb_timer_t *due = NULL;
        for (int i = 0; i < bus->ntimers; i++) {
            pb_timer_t *tm = &bus->timers[i];
            if (tm->next == 0) tm->next = t + tm->period;   /* armed by the first event */
            if (tm->next <= t && (!due || tm->next < due->next)) due = tm;
        }
        if (!due) return;
        int64_t deadline = due->next;
        due->next += due->period;
        if (due->next <= t - 10 * due->period) due->next = t + due->period;  /* skip a long gap */
        if (bus->replay) bus->now = deadline;
        due->fn(bus->replay ? deadline : deadline + wall_offset(bus, t), due->user);
    }
}

int pb_bus_advance(pb_bus_t *bus, int64_t t, pb_err_t *err)
{
    if (bus->replay) {
        fire_timers(bus, t);
        bus->now = t;
        if (bus->publish_failed) { if (err) *err = bus->publish_err; return -1; }
    } else {
        fire_timers(bus, pb_clock_monotonic_utime());
    }
    return 0;
}

static int run_replay(pb_bus_t *bus, pb_err_t *err)
{
    pb_event_t ev;
    if (!bus->in) return pb_err_set(err, "pb_bus_run: this bus has no input log (pb_bus_advance drives it)");
    for (;;) {
        if (bus->stop || pb_signal_stop_requested()) break;
        int r = pb_log_next(bus->in, &ev, err);
        if (r < 0) return -1;
        if (r == 0) break;
        bus->events++;
        fire_timers(bus, ev.timestamp);
        bus->now = ev.timestamp;
        pb_msg_t m = { ev.channel, ev.data, ev.datalen, ev.timestamp };
        for (int i = 0; i < bus->nsubs; i++)
            if (regexec(&bus->subs[i].re, ev.channel, 0, NULL, 0) == 0) deliver(&bus->subs[i], &m);
    }
    if (bus->publish_failed) { if (err) *err = bus->publish_err; return -1; }
    return 0;
}

static int run_live(pb_bus_t *bus, pb_err_t *err)
{
    while (!bus->stop && !pb_signal_stop_requested()) {
        /* Wait for a message at most until the next timer deadline (and 50 ms), so a
         * 100 Hz timer fires on time instead of in bursts after each 50 ms wait. */
        int wait_ms = 50;
        int64_t now = pb_clock_monotonic_utime();
        for (int i = 0; i < bus->ntimers; i++) {
            int64_t next = bus->timers[i].next;
            if (next == 0) continue;
            int64_t ms = next <= now ? 0 : (next - now + 999) / 1000;
            if (ms < wait_ms) wait_ms = (int)ms;
        }
        errno = 0;
        int r = wait_ms > 0 ? lcm_handle_timeout(bus->lcm, wait_ms) : 0;
        if (r < 0 && pb_signal_stop_requested()) break;   /* a signal interrupted the wait */
        if (r < 0 && errno != EINTR) return pb_err_set(err, "lcm_handle failed");
        fire_timers(bus, pb_clock_monotonic_utime());
    }
    return 0;
}

int pb_bus_fileno(const pb_bus_t *bus) { return bus->replay ? -1 : lcm_get_fileno(bus->lcm); }

int pb_bus_dispatch(pb_bus_t *bus, pb_err_t *err)
{
    if (bus->replay) return 0;
    for (int i = 0; i < 1000; i++) {     /* bounded: a flood must not starve the caller */
        errno = 0;
        int r = lcm_handle_timeout(bus->lcm, 0);
        if (r == 0) break;
        /* a signal (SIGCHLD in the supervisor) interrupted select(): not a bus error,
         * the caller dispatches again on its next turn */
        if (r < 0 && errno == EINTR) break;
        if (r < 0) return pb_err_set(err, "lcm_handle failed");
    }
    fire_timers(bus, pb_clock_monotonic_utime());
    return 0;
}

int pb_bus_run(pb_bus_t *bus, pb_err_t *err)
{
    return bus->replay ? run_replay(bus, err) : run_live(bus, err);
}
