/* pb_bus: replay delivers in log order with log time, timers fire on message
 * time, a corrupt input stops the run with the byte offset and keeps OUT; live,
 * messages cross real LCM UDP multicast on a private URL. */
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>
#include <unistd.h>

#include "pb_bus.h"
#include "pb_check.h"
#include "pb_log.h"
#include "pb_status.h"
#include "portobello_status_t.h"

typedef struct {
    pb_bus_t *bus;
    int echoes, others, ticks, received, want;
    int64_t last_tick;
    int order_ok;
    int64_t last_now;
} ctx_t;

static void on_a(const pb_msg_t *m, void *user)
{
    ctx_t *c = user;
    if (pb_bus_now(c->bus) != m->recv_utime) c->order_ok = 0;
    if (m->recv_utime < c->last_now) c->order_ok = 0;
    c->last_now = m->recv_utime;
    pb_bus_publish(c->bus, "ECHO", m->data, m->len, NULL);
    c->echoes++;
}

static void on_other(const pb_msg_t *m, void *user) { ((ctx_t *)user)->others++; }

static void on_tick(int64_t now, void *user)
{
    ctx_t *c = user;
    c->ticks++;
    c->last_tick = now;
    pb_bus_publish(c->bus, "TICK", &now, sizeof now, NULL);
}

static void write_input(const char *path)
{
    pb_log_t *w = pb_log_open_write(path, NULL);
    for (int i = 0; i < 100; i++) {
        int64_t t = 1700000000000000LL + i * 10000;
        pb_log_write(w, t, "A", &i, sizeof i, NULL);
        if (i % 10 == 0) pb_log_write(w, t + 1, i % 20 ? "B" : "C", &i, sizeof i, NULL);
        pb_log_write(w, t + 2, "IGNORED", &i, sizeof i, NULL);
    }
    pb_log_close(w, NULL);
}

static int run_replay(const char *in, const char *out, ctx_t *c, pb_err_t *err)
{
    memset(c, 0, sizeof *c);
    c->order_ok = 1;
    c->bus = pb_bus_create_replay(in, out, err);
    if (!c->bus) return -2;
    pb_bus_subscribe(c->bus, "A", on_a, c);
    pb_bus_subscribe(c->bus, "B|C", on_other, c);
    pb_bus_add_timer(c->bus, 250000, on_tick, c);
    int rc = pb_bus_run(c->bus, err);
    pb_bus_destroy(c->bus);
    return rc;
}

static int count_channel(const char *path, const char *channel, int64_t *first_ts)
{
    pb_log_t *r = pb_log_open_read(path, NULL);
    pb_event_t ev;
    int n = 0;
    while (pb_log_next(r, &ev, NULL) == 1)
        if (strcmp(ev.channel, channel) == 0) {
            if (n == 0 && first_ts) *first_ts = ev.timestamp;
            n++;
        }
    pb_log_close(r, NULL);
    return n;
}

static void on_ping(const pb_msg_t *m, void *user)
{
    ctx_t *c = user;
    int ok = m->len == 300000;
    for (int i = 0; ok && i < m->len; i += 997) ok = m->data[i] == (uint8_t)(i * 7);
    if (ok) c->received++;
    if (c->received == c->want) pb_bus_stop(c->bus);
}

static void on_timeout(int64_t now, void *user) { pb_bus_stop(((ctx_t *)user)->bus); }

static volatile sig_atomic_t g_alarms;
static void on_alarm(int sig) { (void)sig; g_alarms++; }

/* A process with children (the supervisor) gets SIGCHLD at any time; select() inside
 * lcm_handle_timeout then fails with EINTR. That is not a bus error: dispatch must go on
 * (the supervisor used to exit 1 "lcm_handle failed" while stopping its commands). */
static void test_dispatch_survives_signals(const char *url)
{
    pb_err_t err;
    pb_bus_t *bus = pb_bus_create_live(url, &err);
    CHECK(bus != NULL);
    if (!bus) return;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sigemptyset(&sa.sa_mask);
    sa.sa_handler = on_alarm;   /* no SA_RESTART, and select() is never restarted anyway */
    sigaction(SIGALRM, &sa, NULL);
    struct itimerval it = { { 0, 20 }, { 0, 20 } };
    setitimer(ITIMER_REAL, &it, NULL);
    int failed = 0;
    for (int i = 0; i < 30000 && !failed; i++) failed = pb_bus_dispatch(bus, &err) != 0;
    struct itimerval off = { { 0, 0 }, { 0, 0 } };
    setitimer(ITIMER_REAL, &off, NULL);
    signal(SIGALRM, SIG_DFL);
    printf("dispatch under %d signals: %s\n", (int)g_alarms, failed ? err.msg : "no failure");
    CHECK(g_alarms > 100);
    CHECK(!failed);
    pb_bus_destroy(bus);
}

int main(void)
{
    char dir[] = "/tmp/pb_test_bus_XXXXXX";
    if (!mkdtemp(dir)) return 2;
    char in[300], out[300], out2[300], trunc[300], cmd[1400];
    snprintf(in, sizeof in, "%s/in.lcm", dir);
    snprintf(out, sizeof out, "%s/out.lcm", dir);
    snprintf(out2, sizeof out2, "%s/out2.lcm", dir);
    snprintf(trunc, sizeof trunc, "%s/trunc.lcm", dir);
    write_input(in);
    pb_err_t err;
    ctx_t c;

    /* Replay: every event in order, time from the log, timers on message time. */
    CHECK(run_replay(in, out, &c, &err) == 0);
    CHECK(c.echoes == 100);
    CHECK(c.others == 10);
    CHECK(c.order_ok);
    /* Log spans 0 .. 990 ms after the first event: ticks at 250, 500, 750 ms. */
    CHECK(c.ticks == 3);
    CHECK(c.last_tick == 1700000000000000LL + 750000);
    int64_t first_echo = 0, first_tick = 0;
    CHECK(count_channel(out, "ECHO", &first_echo) == 100);
    CHECK(first_echo == 1700000000000000LL);
    CHECK(count_channel(out, "TICK", &first_tick) == 3);
    CHECK(first_tick == 1700000000000000LL + 250000);

    /* Determinism: a second replay writes the same bytes. */
    CHECK(run_replay(in, out2, &c, &err) == 0);
    snprintf(cmd, sizeof cmd, "cmp -s %s %s", out, out2);
    CHECK(system(cmd) == 0);

    /* A torn last event (the input cut short): a clean end after every whole event before
     * the cut (the warning is on stderr), and everything published for them is kept. */
    snprintf(cmd, sizeof cmd, "head -c 4000 %s > %s", in, trunc);
    CHECK(system(cmd) == 0);
    CHECK(run_replay(trunc, out2, &c, &err) == 0);
    CHECK(c.echoes > 10 && c.echoes < 100);
    CHECK(count_channel(out2, "ECHO", NULL) == c.echoes);

    /* Damage inside the file (a bad sync word): stops with the byte offset, keeps what came before. */
    snprintf(cmd, sizeof cmd, "cp %s %s && printf 'JUNK' | dd of=%s bs=1 seek=3975 conv=notrunc status=none", in, trunc, trunc);
    CHECK(system(cmd) == 0);
    CHECK(run_replay(trunc, out2, &c, &err) == -1);
    CHECK_CONTAINS(err.msg, "trunc.lcm: byte 3975: bad sync word");
    CHECK(c.echoes > 10);
    CHECK(count_channel(out2, "ECHO", NULL) == c.echoes);

    /* STATUS carries every counter a module names, however many (the localizer names ~40). */
    {
        pb_bus_t *bus = pb_bus_create_replay(in, out2, &err);
        CHECK(bus != NULL);
        pb_status_t *st = pb_status_create(bus, "many", 1000000);
        char name[32];
        for (int i = 0; i < 45; i++) {
            snprintf(name, sizeof name, "counter_%02d", i);
            pb_status_count(st, name, i + 1);
        }
        CHECK(pb_status_counter(st, "counter_44") == 45);
        CHECK(pb_status_publish(st) == 0);
        pb_status_destroy(st);
        pb_bus_destroy(bus);
        pb_log_t *r = pb_log_open_read(out2, NULL);
        pb_event_t ev;
        int found = 0;
        while (pb_log_next(r, &ev, NULL) == 1) {
            portobello_status_t m;
            if (strcmp(ev.channel, "STATUS") != 0 || portobello_status_t_decode(ev.data, 0, ev.datalen, &m) < 0)
                continue;
            found = 1;
            CHECK(m.ncounters == 45);
            CHECK(m.ncounters == 45 && strcmp(m.counter_names[44], "counter_44") == 0 && m.counter_values[44] == 45);
            portobello_status_t_decode_cleanup(&m);
        }
        pb_log_close(r, NULL);
        CHECK(found);
    }

    /* Missing input: clear error, no bus. */
    CHECK(run_replay("/nonexistent/in.lcm", out2, &c, &err) == -2);
    CHECK_CONTAINS(err.msg, "/nonexistent/in.lcm: cannot open");

    /* URL precedence: --lcm-url, then LCM_DEFAULT_URL, then the project default. */
    setenv("LCM_DEFAULT_URL", "udpm://239.255.76.67:7000?ttl=0", 1);
    CHECK(strcmp(pb_lcm_url("udpm://x"), "udpm://x") == 0);
    CHECK(strcmp(pb_lcm_url(NULL), "udpm://239.255.76.67:7000?ttl=0") == 0);
    unsetenv("LCM_DEFAULT_URL");
    CHECK(strcmp(pb_lcm_url(NULL), PB_DEFAULT_LCM_URL) == 0);

    /* Live: 20 LiDAR-sized messages over real UDP multicast on a private port. */
    const char *url = "udpm://239.255.76.67:7741?ttl=0&recv_buf_size=8388608";
    pb_bus_t *tx = pb_bus_create_live(url, &err);
    ctx_t rx = { 0 };
    rx.bus = pb_bus_create_live(url, &err);
    CHECK(tx && rx.bus);
    if (tx && rx.bus) {
        rx.want = 20;
        pb_bus_subscribe(rx.bus, "PING", on_ping, &rx);
        pb_bus_add_timer(rx.bus, 5000000, on_timeout, &rx);
        static uint8_t big[300000];
        for (int i = 0; i < (int)sizeof big; i++) big[i] = (uint8_t)(i * 7);
        for (int i = 0; i < 20; i++) CHECK(pb_bus_publish(tx, "PING", big, sizeof big, &err) == 0);
        CHECK(pb_bus_run(rx.bus, &err) == 0);
        printf("live: %d of 20 300-KB messages received\n", rx.received);
        CHECK(rx.received == 20);
    }
    pb_bus_destroy(tx);
    pb_bus_destroy(rx.bus);
    test_dispatch_survives_signals("udpm://239.255.76.67:7742?ttl=0");

    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0) return 2;
    return pb_check_report("test_bus");
}
