/* NAV-PVT and NMEA GGA/RMC -> fixes, with the NMEA fallback rule. */
#include "gnss_driver.h"
#include "pb_math.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define DAY_MS 86400000
#define SAME_EPOCH_MS 50       /* NMEA times have 10 ms resolution; epochs are >= 100 ms apart */
#define KNOT_MPS (1852.0 / 3600.0)

static const char *const COUNTER_NAMES[GNSS_C_COUNT] = {
    "ubx_frames", "ubx_nav_pvt", "nmea_sentences", "nmea_gga", "nmea_rmc", "nmea_gst",
    "rtcm3_frames", "fixes_ubx", "fixes_nmea", "nmea_fills", "nmea_suppressed",
    "skipped_bytes",
    "ubx_bad_checksum", "ubx_too_long", "ubx_truncated", "nav_pvt_bad_length",
    "nmea_bad_checksum", "nmea_no_checksum", "nmea_bad_char", "nmea_too_long",
    "nmea_truncated", "nmea_bad_field", "pvt_no_utc", "nmea_no_date",
};

const char *gnss_counter_name(gnss_counter_t c)
{
    return (unsigned)c < GNSS_C_COUNT ? COUNTER_NAMES[c] : "unknown";
}

typedef struct {
    int active;
    int32_t tod_ms;
    int64_t offset;
    int have_gga, have_rmc, have_gst;
    gnss_nmea_gga_t gga;
    gnss_nmea_rmc_t rmc;
    gnss_nmea_gst_t gst;
} nmea_epoch_t;

struct gnss_driver {
    gnss_driver_config_t cfg;
    gnss_driver_handlers_t h;
    gnss_stream_t *stream;
    int64_t counters[GNSS_C_COUNT];
    int32_t last_pvt_tod;      /* -1: no timed NAV-PVT yet */
    int pvt_leads;             /* learned: NAV-PVT comes before the NMEA of its epoch */
    int gst_seen;              /* learned: this stream sends GST (epochs wait for it) */
    int64_t date_days;         /* latest known UTC date (days since 1970), -1 none */
    int32_t date_tod;          /* time of day it was known at */
    nmea_epoch_t pending;
};

void gnss_driver_config_default(gnss_driver_config_t *c)
{
    gnss_stream_config_default(&c->stream);
    c->nmea_holdoff_ms = 2000;
}

int64_t gnss_days_from_civil(int y, int m, int d)
{
    /* Howard Hinnant's days_from_civil. */
    y -= m <= 2;
    int64_t era = (y >= 0 ? y : y - 399) / 400;
    int64_t yoe = y - era * 400;
    int64_t doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
    int64_t doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    return era * 146097 + doe - 719468;
}

static int32_t tod_diff(int32_t a, int32_t b)
{
    int32_t d = (a - b) % DAY_MS;
    if (d < -DAY_MS / 2) d += DAY_MS;
    if (d >= DAY_MS / 2) d -= DAY_MS;
    return d;
}

static void count_error(gnss_driver_t *d, gnss_counter_t c, int64_t offset, const char *detail)
{
    d->counters[c]++;
    if (d->h.on_error) d->h.on_error(d->h.user, c, offset, detail);
}

static void emit(gnss_driver_t *d, const gnss_fix_out_t *fix)
{
    d->counters[fix->source == GNSS_SRC_NMEA ? GNSS_C_FIXES_NMEA : GNSS_C_FIXES_UBX]++;
    if (d->h.on_fix) d->h.on_fix(d->h.user, fix);
}

/* ---------------------------------------------------------------- NAV-PVT */

static int pvt_utc_ok(const gnss_nav_pvt_t *p)
{
    return (p->valid & GNSS_PVT_VALID_DATE) && (p->valid & GNSS_PVT_VALID_TIME) &&
           p->year >= 1980 && p->month >= 1 && p->month <= 12 && p->day >= 1 && p->day <= 31 &&
           p->hour < 24 && p->min < 60 && p->sec <= 60 && p->nano > -1000000000 && p->nano < 1000000000;
}

static double norm360(double deg)
{
    double h = fmod(deg, 360.0);
    return h < 0 ? h + 360.0 : h;
}

void gnss_fix_from_nav_pvt(const gnss_nav_pvt_t *p, gnss_fix_out_t *f)
{
    memset(f, 0, sizeof *f);
    f->source = GNSS_SRC_UBX_NAV_PVT;
    int8_t ft = p->fix_type <= 5 ? (int8_t)p->fix_type : GNSS_FIX_NONE;
    int carr = (p->flags >> 6) & 3;
    if (ft >= GNSS_FIX_2D && ft <= GNSS_FIX_GNSS_DR && carr == 1) ft = GNSS_FIX_RTK_FLOAT;
    if (ft >= GNSS_FIX_2D && ft <= GNSS_FIX_GNSS_DR && carr == 2) ft = GNSS_FIX_RTK_FIXED;
    /* gnssFixOK clear: the receiver says the fix is outside its DOP/accuracy masks. */
    if (!(p->flags & GNSS_PVT_FLAG_FIX_OK) && ft != GNSS_FIX_TIME_ONLY) ft = GNSS_FIX_NONE;
    int llh_ok = !(p->flags3 & GNSS_PVT_FLAGS3_INVALID_LLH);
    if (!llh_ok) ft = GNSS_FIX_NONE;
    f->fix_type = ft;
    f->num_sv = p->num_sv;
    f->lat_deg = llh_ok ? p->lat / 1e7 : NAN;
    f->lon_deg = llh_ok ? p->lon / 1e7 : NAN;
    f->alt_m = llh_ok ? p->height_mm / 1e3 : NAN;
    f->alt_msl_m = llh_ok ? p->hmsl_mm / 1e3 : NAN;
    f->h_acc_m = p->h_acc_mm / 1e3;
    f->v_acc_m = p->v_acc_mm / 1e3;
    f->vel_ned_mps[0] = p->vel_n / 1e3;
    f->vel_ned_mps[1] = p->vel_e / 1e3;
    f->vel_ned_mps[2] = p->vel_d / 1e3;
    f->speed_mps = p->g_speed / 1e3;
    f->heading_deg = norm360(p->head_mot / 1e5);
    f->heading_acc_deg = p->head_acc / 1e5;
    if (pvt_utc_ok(p)) {
        f->has_utime = 1;
        int64_t days = gnss_days_from_civil(p->year, p->month, p->day);
        int64_t s = days * 86400 + p->hour * 3600 + p->min * 60 + p->sec;
        f->utime = s * 1000000 + pb_floor_div((int64_t)p->nano + 500, 1000);
    }
}

/* ---------------------------------------------------------------- NMEA epochs */

static int8_t fix_type_gga(const gnss_nmea_gga_t *g)
{
    switch (g->quality) {
    case 1: case 2: case 3: return isnan(g->alt_msl_m) ? GNSS_FIX_2D : GNSS_FIX_3D;
    case 4: return GNSS_FIX_RTK_FIXED;
    case 5: return GNSS_FIX_RTK_FLOAT;
    case 6: return GNSS_FIX_DEAD_RECKONING;
    default: return GNSS_FIX_NONE;   /* 0 invalid, 7 manual, 8 simulator, empty */
    }
}

static int8_t fix_type_rmc(const gnss_nmea_rmc_t *r)
{
    switch (r->mode) {
    case 'A': case 'D': return GNSS_FIX_2D;     /* RMC carries no height */
    case 'E': return GNSS_FIX_DEAD_RECKONING;
    case 'F': return GNSS_FIX_RTK_FLOAT;
    case 'R': return GNSS_FIX_RTK_FIXED;
    case 0: return r->status == 'A' ? GNSS_FIX_2D : GNSS_FIX_NONE;
    default: return GNSS_FIX_NONE;
    }
}

static void fix_from_epoch(gnss_driver_t *d, const nmea_epoch_t *e, gnss_fix_out_t *f)
{
    memset(f, 0, sizeof *f);
    f->source = GNSS_SRC_NMEA;
    f->offset = e->offset;
    f->num_sv = -1;
    f->lat_deg = f->lon_deg = f->alt_m = f->alt_msl_m = f->h_acc_m = f->v_acc_m = NAN;
    f->vel_ned_mps[0] = f->vel_ned_mps[1] = f->vel_ned_mps[2] = NAN;
    f->speed_mps = f->heading_deg = f->heading_acc_deg = NAN;
    int has_pos = 0;
    if (e->have_gga) {
        f->fix_type = fix_type_gga(&e->gga);
        f->num_sv = (int16_t)e->gga.num_sv;
        if (e->gga.has_pos) {
            has_pos = 1;
            f->lat_deg = e->gga.lat_deg;
            f->lon_deg = e->gga.lon_deg;
        }
        f->alt_msl_m = e->gga.alt_msl_m;
        f->alt_m = e->gga.alt_msl_m + e->gga.geoid_sep_m;   /* NaN if either is empty */
    } else {
        f->fix_type = fix_type_rmc(&e->rmc);
    }
    if (e->have_rmc) {
        if (!has_pos && e->rmc.has_pos) {
            has_pos = 1;
            f->lat_deg = e->rmc.lat_deg;
            f->lon_deg = e->rmc.lon_deg;
        }
        f->speed_mps = e->rmc.speed_knots * KNOT_MPS;
        f->heading_deg = e->rmc.course_deg == 360.0 ? 0.0 : e->rmc.course_deg;
        if (!isnan(f->speed_mps) && !isnan(f->heading_deg)) {
            double c = f->heading_deg * M_PI / 180.0;
            f->vel_ned_mps[0] = f->speed_mps * cos(c);
            f->vel_ned_mps[1] = f->speed_mps * sin(c);
        }
    }
    if (!has_pos) f->fix_type = GNSS_FIX_NONE;
    if (e->have_gst) {
        /* Horizontal RMS from the per-axis sigmas: the definition of h_acc_m. */
        f->h_acc_m = sqrt(e->gst.std_lat_m * e->gst.std_lat_m + e->gst.std_lon_m * e->gst.std_lon_m);
        f->v_acc_m = e->gst.std_alt_m;
    }

    /* Date: RMC of this epoch, else the latest date seen (RMC or NAV-PVT), moved on a
     * day when the time of day wrapped past midnight since. */
    int64_t days = -1;
    if (e->have_rmc && e->rmc.has_date) {
        days = gnss_days_from_civil(e->rmc.year, e->rmc.month, e->rmc.day);
    } else if (d->date_days >= 0) {
        int32_t dt = e->tod_ms - d->date_tod;
        days = d->date_days + (dt < -DAY_MS / 2 ? 1 : dt >= DAY_MS / 2 ? -1 : 0);
    }
    if (days >= 0) {
        f->has_utime = 1;
        f->utime = (days * 86400000LL + e->tod_ms) * 1000;
        d->date_days = days;
        d->date_tod = e->tod_ms;
    }
}

static void decide_epoch(gnss_driver_t *d)
{
    nmea_epoch_t *e = &d->pending;
    if (!e->active) return;
    e->active = 0;
    if (!e->have_gga && !e->have_rmc) return;   /* GST alone (e.g. after its epoch was decided) */
    int publish;
    int fill = 0;
    if (d->last_pvt_tod < 0) {
        publish = 1;
    } else {
        int32_t dt = tod_diff(e->tod_ms, d->last_pvt_tod);
        if (abs(dt) > d->cfg.nmea_holdoff_ms) publish = 1;
        else if (abs(dt) < SAME_EPOCH_MS) { publish = 0; d->pvt_leads = 1; }
        else if (dt > 0 && d->pvt_leads) { publish = 1; fill = 1; }
        else publish = 0;
    }
    gnss_fix_out_t f;
    fix_from_epoch(d, e, &f);   /* also when suppressed: keeps the date current */
    if (!publish) { d->counters[GNSS_C_NMEA_SUPPRESSED]++; return; }
    if (fill) d->counters[GNSS_C_NMEA_FILLS]++;
    if (!f.has_utime) {
        char msg[96];
        snprintf(msg, sizeof msg, "NMEA fix without a UTC date (no RMC or NAV-PVT date seen yet)");
        count_error(d, GNSS_C_NMEA_NO_DATE, e->offset, msg);
    }
    emit(d, &f);
}

static void on_nmea_time(gnss_driver_t *d, int64_t offset, int32_t tod)
{
    nmea_epoch_t *e = &d->pending;
    if (e->active && e->tod_ms != tod) decide_epoch(d);
    if (!e->active) {
        memset(e, 0, sizeof *e);
        e->active = 1;
        e->tod_ms = tod;
        e->offset = offset;
    }
}

/* ---------------------------------------------------------------- stream callbacks */

static void on_ubx(void *user, int64_t offset, const gnss_ubx_frame_t *fr)
{
    gnss_driver_t *d = user;
    d->counters[GNSS_C_UBX_FRAMES]++;
    if (fr->msg_class != GNSS_UBX_CLASS_NAV || fr->msg_id != GNSS_UBX_ID_NAV_PVT) return;
    d->counters[GNSS_C_UBX_NAV_PVT]++;
    gnss_nav_pvt_t p;
    if (gnss_ubx_nav_pvt_decode(fr->payload, fr->len, &p) != 0) {
        char msg[96];
        snprintf(msg, sizeof msg, "NAV-PVT payload of %u bytes (at least %d expected)", fr->len,
                 GNSS_UBX_NAV_PVT_LEN_MIN);
        count_error(d, GNSS_C_NAV_PVT_BAD_LENGTH, offset, msg);
        return;
    }
    gnss_fix_out_t f;
    gnss_fix_from_nav_pvt(&p, &f);
    f.offset = offset;
    if (f.has_utime) {
        int32_t tod = (int32_t)(((int64_t)p.hour * 3600000 + p.min * 60000 + p.sec * 1000 +
                                 pb_floor_div((int64_t)p.nano + 500000, 1000000)) % DAY_MS);
        if (tod < 0) tod += DAY_MS;
        /* NMEA of this same epoch already waiting: NMEA leads on this stream. */
        if (d->pending.active && abs(tod_diff(d->pending.tod_ms, tod)) < SAME_EPOCH_MS) {
            d->pending.active = 0;
            if (d->pending.have_gga || d->pending.have_rmc) {
                d->counters[GNSS_C_NMEA_SUPPRESSED]++;
                d->pvt_leads = 0;
            }
        } else {
            decide_epoch(d);
        }
        d->last_pvt_tod = tod;
        d->date_days = gnss_days_from_civil(p.year, p.month, p.day);
        d->date_tod = tod;
    } else {
        decide_epoch(d);
        count_error(d, GNSS_C_PVT_NO_UTC, offset, "NAV-PVT without a valid UTC date and time");
    }
    emit(d, &f);
}

static void on_nmea(void *user, int64_t offset, const gnss_nmea_sentence_t *s)
{
    gnss_driver_t *d = user;
    d->counters[GNSS_C_NMEA_SENTENCES]++;
    int gga = strcmp(s->type, "GGA") == 0, rmc = strcmp(s->type, "RMC") == 0;
    int gst = strcmp(s->type, "GST") == 0;
    if (!gga && !rmc && !gst) return;
    d->counters[gga ? GNSS_C_NMEA_GGA : rmc ? GNSS_C_NMEA_RMC : GNSS_C_NMEA_GST]++;
    gnss_nmea_gga_t g;
    gnss_nmea_rmc_t r;
    gnss_nmea_gst_t t;
    int bad = 0;
    int rc = gga ? gnss_nmea_parse_gga(s, &g, &bad) : rmc ? gnss_nmea_parse_rmc(s, &r, &bad)
                                                         : gnss_nmea_parse_gst(s, &t, &bad);
    if (rc != 0) {
        char msg[96];
        snprintf(msg, sizeof msg, "%s: field %d malformed", s->address, bad);
        count_error(d, GNSS_C_NMEA_BAD_FIELD, offset, msg);
        return;
    }
    int32_t tod = gga ? g.tod_ms : rmc ? r.tod_ms : t.tod_ms;
    if (tod < 0 && gst) return;   /* accuracy without a time: nothing to attach it to */
    if (tod < 0) {
        char msg[96];
        snprintf(msg, sizeof msg, "%s without a UTC time: not a fix", s->address);
        count_error(d, GNSS_C_NMEA_NO_DATE, offset, msg);
        return;
    }
    on_nmea_time(d, offset, tod);
    nmea_epoch_t *e = &d->pending;
    if (gga && !e->have_gga) { e->gga = g; e->have_gga = 1; }
    if (rmc && !e->have_rmc) { e->rmc = r; e->have_rmc = 1; }
    if (gst && !e->have_gst) { e->gst = t; e->have_gst = 1; d->gst_seen = 1; }
    if (e->have_gga && e->have_rmc && (e->have_gst || !d->gst_seen)) decide_epoch(d);
}

static void on_rtcm3(void *user, int64_t offset, int type, size_t total)
{
    ((gnss_driver_t *)user)->counters[GNSS_C_RTCM3_FRAMES]++;
}

static void on_stream_error(void *user, int64_t offset, gnss_stream_error_t e, const char *detail)
{
    static const gnss_counter_t map[GNSS_ERR_COUNT] = {
        GNSS_C_UBX_BAD_CHECKSUM, GNSS_C_UBX_TOO_LONG, GNSS_C_UBX_TRUNCATED,
        GNSS_C_NMEA_BAD_CHECKSUM, GNSS_C_NMEA_NO_CHECKSUM, GNSS_C_NMEA_BAD_CHAR, GNSS_C_NMEA_TOO_LONG,
        GNSS_C_NMEA_TRUNCATED,
    };
    count_error(user, map[e], offset, detail);
}

static void on_skip(void *user, int64_t offset, int64_t n)
{
    ((gnss_driver_t *)user)->counters[GNSS_C_SKIPPED_BYTES] += n;
}

gnss_driver_t *gnss_driver_create(const gnss_driver_config_t *cfg, const gnss_driver_handlers_t *h)
{
    gnss_driver_t *d = calloc(1, sizeof *d);
    if (!d) return NULL;
    if (cfg) d->cfg = *cfg;
    else gnss_driver_config_default(&d->cfg);
    if (h) d->h = *h;
    d->last_pvt_tod = -1;
    d->date_days = -1;
    gnss_stream_handlers_t sh = {
        .on_ubx = on_ubx, .on_nmea = on_nmea, .on_rtcm3 = on_rtcm3,
        .on_error = on_stream_error, .on_skip = on_skip, .user = d,
    };
    d->stream = gnss_stream_create(&d->cfg.stream, &sh);
    if (!d->stream) { free(d); return NULL; }
    return d;
}

void gnss_driver_destroy(gnss_driver_t *d)
{
    if (!d) return;
    gnss_stream_destroy(d->stream);
    free(d);
}

void gnss_driver_feed(gnss_driver_t *d, const uint8_t *data, size_t n) { gnss_stream_feed(d->stream, data, n); }

void gnss_driver_finish(gnss_driver_t *d)
{
    gnss_stream_finish(d->stream);
    decide_epoch(d);
}

void gnss_driver_stop(gnss_driver_t *d) { decide_epoch(d); }

int64_t gnss_driver_counter(const gnss_driver_t *d, gnss_counter_t c)
{
    return (unsigned)c < GNSS_C_COUNT ? d->counters[c] : 0;
}

int64_t gnss_driver_offset(const gnss_driver_t *d) { return gnss_stream_offset(d->stream); }
