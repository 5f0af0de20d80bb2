/* STATUS heartbeat: per-input counts, ages and rates, named counters, last error. */
#include "pb_status.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "portobello_status_t.h"

typedef struct {
    char name[64];
    int64_t count, count_at_beat, last_utime;
} pb_input_t;

typedef struct {
    char name[64];
    int64_t value;
} pb_counter_t;

struct pb_status {
    pb_bus_t *bus;
    char module[64];
    int64_t period;
    int8_t state;
    /* Grown as channels and counters appear: STATUS carries every one a module names. */
    pb_input_t *inputs;
    int ninputs, cap_inputs;
    pb_counter_t *counters;
    int ncounters, cap_counters;
    char last_error[512];
    int64_t module_time;
};

/* Room for one more element of a growable array; 0, or -1 when out of memory. */
static int grow(void **items, int *cap, int n, size_t size)
{
    if (n < *cap) return 0;
    int want = *cap ? 2 * *cap : 16;
    void *p = realloc(*items, (size_t)want * size);
    if (!p) return -1;
    *items = p;
    *cap = want;
    return 0;
}

static pb_input_t *input(pb_status_t *st, const char *channel)
{
    for (int i = 0; i < st->ninputs; i++)
        if (strcmp(st->inputs[i].name, channel) == 0) return &st->inputs[i];
    if (grow((void **)&st->inputs, &st->cap_inputs, st->ninputs, sizeof *st->inputs) != 0) return NULL;
    pb_input_t *in = &st->inputs[st->ninputs++];
    memset(in, 0, sizeof *in);
    snprintf(in->name, sizeof in->name, "%s", channel);
    return in;
}

static void on_input(const char *channel, int64_t recv_utime, void *user)
{
    pb_input_t *in = input(user, channel);
    if (in) in->count++;
}

static void on_timer(int64_t now, void *user) { pb_status_publish(user); }

pb_status_t *pb_status_create(pb_bus_t *bus, const char *module, int64_t period_us)
{
    pb_status_t *st = calloc(1, sizeof *st);
    st->bus = bus;
    snprintf(st->module, sizeof st->module, "%s", module);
    st->period = period_us > 0 ? period_us : 1000000;
    st->state = PORTOBELLO_STATUS_T_STATE_STARTING;
    pb_bus_set_input_hook(bus, on_input, st);
    pb_bus_add_timer(bus, st->period, on_timer, st);
    /* Live, the first heartbeat goes out at once: a supervisor sees a (re)started
     * module within milliseconds, not a period later. Replay keeps its log-time grid. */
    if (!pb_bus_is_replay(bus)) pb_status_publish(st);
    return st;
}

void pb_status_destroy(pb_status_t *st)
{
    if (!st) return;
    pb_bus_set_input_hook(st->bus, NULL, NULL);
    free(st->inputs);
    free(st->counters);
    free(st);
}

void pb_status_input_time(pb_status_t *st, const char *channel, int64_t msg_utime)
{
    pb_input_t *in = input(st, channel);
    if (in && msg_utime > in->last_utime) in->last_utime = msg_utime;
    if (msg_utime > st->module_time) st->module_time = msg_utime;
}

static pb_counter_t *counter(pb_status_t *st, const char *name, int create)
{
    for (int i = 0; i < st->ncounters; i++)
        if (strcmp(st->counters[i].name, name) == 0) return &st->counters[i];
    if (!create || grow((void **)&st->counters, &st->cap_counters, st->ncounters, sizeof *st->counters) != 0)
        return NULL;
    pb_counter_t *c = &st->counters[st->ncounters++];
    snprintf(c->name, sizeof c->name, "%s", name);
    c->value = 0;
    return c;
}

void pb_status_count(pb_status_t *st, const char *name, int64_t increment)
{
    pb_counter_t *c = counter(st, name, 1);
    if (c) c->value += increment;
}

int64_t pb_status_counter(const pb_status_t *st, const char *name)
{
    pb_counter_t *c = counter((pb_status_t *)st, name, 0);
    return c ? c->value : 0;
}

void pb_status_error(pb_status_t *st, const char *fmt, ...)
{
    char msg[sizeof st->last_error];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (strcmp(msg, st->last_error) != 0) fprintf(stderr, "%s: %s\n", st->module, msg);
    memcpy(st->last_error, msg, sizeof msg);
}

void pb_status_set_state(pb_status_t *st, int8_t state) { st->state = state; }

void pb_status_undecodable(pb_status_t *st, const char *counter, const pb_msg_t *msg)
{
    pb_status_count(st, counter, 1);
    pb_status_error(st, "%s: message of %d bytes does not decode", msg->channel, msg->len);
}

int pb_status_scan_points(pb_status_t *st, const portobello_lidar_scan_t *s, pb_points_t *pts)
{
    pb_err_t err;
    int n = pb_scan_points(s, pts, &err);
    if (n < 0) {
        pb_status_count(st, "scan_invalid", 1);
        pb_status_error(st, "%s (seq %d)", err.msg, s->seq);
        return -1;
    }
    if (n == s->npoints || s->npoints == 0) return n;
    int bad = 0;
    for (int i = 0; i < s->npoints; i++)
        if (!isfinite(s->x[i]) || !isfinite(s->y[i]) || !isfinite(s->z[i])) bad++;
    if (bad) {
        pb_status_count(st, "scan_nonfinite_points", bad);
        pb_status_error(st, "LIDAR_SCAN seq %d: %d NaN/inf points dropped", s->seq, bad);
    }
    return n;
}

int pb_status_finish(pb_status_t *st, const char *error)
{
    st->state = error ? PORTOBELLO_STATUS_T_STATE_ERROR : PORTOBELLO_STATUS_T_STATE_STOPPING;
    if (error) {
        fprintf(stderr, "%s: %s\n", st->module, error);
        snprintf(st->last_error, sizeof st->last_error, "%s", error);
    }
    return pb_status_publish(st);
}

int pb_status_publish(pb_status_t *st)
{
    /* Module time: the newest input message time, else the bus clock. */
    int64_t now = pb_bus_now(st->bus);
    int64_t mt = st->module_time ? st->module_time : now;
    portobello_input_status_t *inputs = calloc((size_t)st->ninputs + 1, sizeof *inputs);
    char **names = calloc((size_t)st->ncounters + 1, sizeof *names);
    int64_t *values = calloc((size_t)st->ncounters + 1, sizeof *values);
    if (!inputs || !names || !values) {
        free(inputs);
        free(names);
        free(values);
        fprintf(stderr, "%s: STATUS: out of memory\n", st->module);
        return -1;
    }
    for (int i = 0; i < st->ninputs; i++) {
        pb_input_t *in = &st->inputs[i];
        inputs[i].channel = in->name;
        inputs[i].count = in->count;
        /* Ages on the bus clock (log time in replay), so a silent input ages live. */
        inputs[i].age_s = in->last_utime ? (float)((now - in->last_utime) * 1e-6) : -1.0f;
        inputs[i].rate_hz = (float)((in->count - in->count_at_beat) * 1e6 / (double)st->period);
        in->count_at_beat = in->count;
    }
    for (int i = 0; i < st->ncounters; i++) {
        names[i] = st->counters[i].name;
        values[i] = st->counters[i].value;
    }
    portobello_status_t msg = {
        .utime = mt,
        .module = st->module,
        .pid = pb_bus_is_replay(st->bus) ? 0 : (int32_t)getpid(),
        .state = st->state,
        .ninputs = st->ninputs,
        .inputs = inputs,
        .ncounters = st->ncounters,
        .counter_names = names,
        .counter_values = values,
        .last_error = st->last_error,
    };
    pb_err_t err;
    int rc = PB_PUBLISH(st->bus, "STATUS", portobello_status_t, &msg, &err);
    if (rc != 0) fprintf(stderr, "%s: STATUS: %s\n", st->module, err.msg);
    free(inputs);
    free(names);
    free(values);
    return rc != 0 ? -1 : 0;
}
