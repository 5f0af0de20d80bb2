/* Speed decoding through the DBC (see can_speed.h). */
#include "can_speed.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct can_speed_dec {
    can_speed_config_t cfg;
    const can_dbc_t *dbc;
    const can_message_t *first;         /* message index = msg - first */
    const can_signal_t **checksum_sig;  /* per DBC message: its CHECKSUM signal or NULL */
    const can_message_t *wheel_msg, *speed_msg, *yaw_msg, *gear_msg;
    const can_signal_t *wheel[4], *speed_sig, *yaw_sig, *gear_sig;
    int64_t gear_reverse_raw, gear_utime;
    int have_gear, reverse;
    double wheel_scale, speed_scale, yaw_scale;     /* DBC unit -> m/s, rad/s */
    int64_t last_utime, yaw_utime;
    int have_time, have_yaw;
    double yaw_rps;
};

void can_speed_config_default(can_speed_config_t *cfg)
{
    *cfg = (can_speed_config_t){
        .bus = 0, .checksum = CAN_CHECKSUM_NONE,
        .wheel_msg = "WHEEL_SPEEDS", .wheel_fl = "WHEEL_SPEED_FL", .wheel_fr = "WHEEL_SPEED_FR",
        .wheel_rl = "WHEEL_SPEED_RL", .wheel_rr = "WHEEL_SPEED_RR",
        .speed_msg = "SPEED", .speed_sig = "SPEED",
        .yaw_msg = "KINEMATICS", .yaw_sig = "YAW_RATE",
        .yaw_max_age_us = 50000,
        .gear_msg = "GEAR_PACKET", .gear_sig = "GEAR", .gear_reverse = "R",
        .gear_max_age_us = 5000000,
    };
}

static const char *const verdict_names[CAN_V_COUNT] = {
    [CAN_V_SPEED] = "speed", [CAN_V_DECODED] = "decoded", [CAN_V_OTHER_BUS] = "other_bus",
    [CAN_V_UNKNOWN_ID] = "unknown_id", [CAN_V_ERROR_FRAME] = "error_frame",
    [CAN_V_REMOTE_FRAME] = "remote_frame", [CAN_V_BAD_LENGTH] = "bad_length",
    [CAN_V_BAD_CHECKSUM] = "bad_checksum",
};

const char *can_verdict_name(can_verdict_t v)
{
    return (unsigned)v < CAN_V_COUNT ? verdict_names[v] : "invalid";
}

uint8_t can_checksum_toyota(uint32_t id, const uint8_t *data, int len)
{
    /* opendbc can/common.cc toyota_checksum: length + every byte of the address + data
     * bytes before the checksum byte, modulo 256. */
    unsigned s = (unsigned)len;
    for (uint32_t a = id; a; a >>= 8) s += a & 0xFF;
    for (int i = 0; i < len - 1; i++) s += data[i];
    return (uint8_t)s;
}

/* m/s per unit of speed, rad/s per unit of rate; 0 if the unit is not one we know. */
static double speed_unit(const char *u)
{
    if (!strcmp(u, "km/h") || !strcmp(u, "kph")) return 1.0 / 3.6;
    if (!strcmp(u, "m/s")) return 1.0;
    if (!strcmp(u, "mph")) return 0.44704;
    return 0;
}

static double rate_unit(const char *u)
{
    if (!strcmp(u, "deg/s")) return M_PI / 180.0;
    if (!strcmp(u, "rad/s")) return 1.0;
    return 0;
}

static int lookup_signal(const can_message_t *m, const char *name, const can_signal_t **out,
                         double (*unit)(const char *), double *scale, pb_err_t *err)
{
    const can_signal_t *s = can_message_signal(m, name);
    if (!s) return pb_err_set(err, "DBC message %s has no signal %s", m->name, name);
    if (s->multiplexed) return pb_err_set(err, "DBC signal %s.%s is multiplexed (not supported for speeds)", m->name, name);
    double k = unit(s->unit);
    if (k == 0) return pb_err_set(err, "DBC signal %s.%s: unit '%s' is not a speed or rate unit this decoder knows", m->name, name, s->unit);
    if (*scale != 0 && *scale != k) return pb_err_set(err, "DBC message %s: wheel speeds in different units", m->name);
    *scale = k;
    *out = s;
    return 0;
}

can_speed_dec_t *can_speed_create(const can_dbc_t *dbc, const can_speed_config_t *cfg, pb_err_t *err)
{
    can_speed_dec_t *d = calloc(1, sizeof *d);
    int n = can_dbc_message_count(dbc);
    if (!d || !(d->checksum_sig = calloc((size_t)(n ? n : 1), sizeof *d->checksum_sig))) {
        free(d);
        pb_err_set(err, "out of memory");
        return NULL;
    }
    d->cfg = *cfg;
    d->dbc = dbc;
    d->first = can_dbc_message_at(dbc, 0);
    for (int i = 0; i < n; i++) {
        const can_signal_t *s = can_message_signal(can_dbc_message_at(dbc, i), "CHECKSUM");
        if (s && !s->multiplexed) d->checksum_sig[i] = s;
    }
    d->speed_msg = cfg->speed_msg ? can_dbc_find_name(dbc, cfg->speed_msg) : NULL;
    if (!d->speed_msg) {
        pb_err_set(err, "the DBC has no speed message '%s'", cfg->speed_msg ? cfg->speed_msg : "(none)");
        goto bad;
    }
    if (lookup_signal(d->speed_msg, cfg->speed_sig, &d->speed_sig, speed_unit, &d->speed_scale, err)) goto bad;
    d->wheel_msg = cfg->wheel_msg ? can_dbc_find_name(dbc, cfg->wheel_msg) : NULL;
    if (d->wheel_msg) {
        const char *names[4] = { cfg->wheel_fl, cfg->wheel_fr, cfg->wheel_rl, cfg->wheel_rr };
        for (int k = 0; k < 4; k++)
            if (lookup_signal(d->wheel_msg, names[k], &d->wheel[k], speed_unit, &d->wheel_scale, err)) goto bad;
    }
    d->yaw_msg = cfg->yaw_msg ? can_dbc_find_name(dbc, cfg->yaw_msg) : NULL;
    if (d->yaw_msg && lookup_signal(d->yaw_msg, cfg->yaw_sig, &d->yaw_sig, rate_unit, &d->yaw_scale, err)) goto bad;
    /* the gear, when the DBC has the message, the signal and "R" in its value table */
    d->gear_msg = cfg->gear_msg ? can_dbc_find_name(dbc, cfg->gear_msg) : NULL;
    d->gear_sig = d->gear_msg && cfg->gear_sig ? can_message_signal(d->gear_msg, cfg->gear_sig) : NULL;
    if (!d->gear_sig || d->gear_sig->multiplexed || !cfg->gear_reverse ||
        can_dbc_value_raw(dbc, d->gear_msg, cfg->gear_sig, cfg->gear_reverse, &d->gear_reverse_raw) != 0)
        d->gear_msg = NULL;
    return d;
bad:
    can_speed_destroy(d);
    return NULL;
}

void can_speed_destroy(can_speed_dec_t *dec)
{
    if (!dec) return;
    free(dec->checksum_sig);
    free(dec);
}

static double value(const can_signal_t *s, const can_rx_t *f, double scale)
{
    return can_signal_value(s, f->data, f->len, NULL) * scale;
}

can_verdict_t can_speed_decode(can_speed_dec_t *d, const can_rx_t *f, can_speed_t *out, int *time_backwards)
{
    int back = d->have_time && f->utime < d->last_utime;
    if (time_backwards) *time_backwards = back;
    if (!back) { d->last_utime = f->utime; d->have_time = 1; }

    if (f->error) return CAN_V_ERROR_FRAME;
    if (d->cfg.bus >= 0 && f->bus != d->cfg.bus) return CAN_V_OTHER_BUS;
    if (f->rtr) return CAN_V_REMOTE_FRAME;
    const can_message_t *m = can_dbc_find(d->dbc, f->id, f->extended);
    if (!m) return CAN_V_UNKNOWN_ID;
    if (f->len != m->length) return CAN_V_BAD_LENGTH;
    const can_signal_t *ck = d->checksum_sig[m - d->first];
    if (ck && d->cfg.checksum == CAN_CHECKSUM_TOYOTA && f->len >= 1 &&
        (uint64_t)can_signal_raw(ck, f->data) != can_checksum_toyota(f->id, f->data, f->len))
        return CAN_V_BAD_CHECKSUM;

    if (m == d->yaw_msg) {
        d->yaw_rps = value(d->yaw_sig, f, d->yaw_scale);
        d->yaw_utime = f->utime;
        d->have_yaw = 1;
    }
    if (m == d->gear_msg) {
        d->reverse = can_signal_raw(d->gear_sig, f->data) == d->gear_reverse_raw;
        d->gear_utime = f->utime;
        d->have_gear = 1;
    }
    if (m != d->wheel_msg && m != d->speed_msg) return CAN_V_DECODED;

    memset(out, 0, sizeof *out);
    out->utime = f->utime;
    out->source = m->name;
    if (m == d->wheel_msg) {
        double sum = 0;
        for (int k = 0; k < 4; k++) sum += out->wheel_speed_mps[k] = value(d->wheel[k], f, d->wheel_scale);
        out->has_wheel_speeds = 1;
        out->speed_mps = sum / 4;
    } else {
        out->speed_mps = value(d->speed_sig, f, d->speed_scale);
    }
    /* Speeds are magnitudes (Toyota): the gear gives the direction, while it is recent */
    if (d->have_gear && llabs(f->utime - d->gear_utime) <= d->cfg.gear_max_age_us) {
        out->has_gear = 1;
        out->reverse = d->reverse;
        if (d->reverse) out->speed_mps = -fabs(out->speed_mps);
    }
    /* A yaw rate from the last yaw_max_age_us (either side: logs may interleave buses). */
    if (d->have_yaw && llabs(f->utime - d->yaw_utime) <= d->cfg.yaw_max_age_us) {
        out->has_yaw_rate = 1;
        out->yaw_rate_rps = d->yaw_rps;
    }
    return CAN_V_SPEED;
}
