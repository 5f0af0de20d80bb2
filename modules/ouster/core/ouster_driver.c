/* Ouster driver core: packets -> frames -> LIDAR_SCAN and IMU (see ouster_driver.h). */
#include "ouster_driver.h"

#include <math.h>
#include <stdint.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum {
    C_LIDAR_PACKETS, C_IMU_PACKETS, C_FRAMES, C_IMU_SAMPLES,
    C_FRAMES_INCOMPLETE, C_COLUMNS_MISSING, C_COLUMNS_STATUS_INVALID,
    C_LIDAR_WRONG_SIZE, C_LIDAR_WRONG_PACKET_TYPE, C_LIDAR_WRONG_SENSOR,
    C_COLUMN_BAD_MEASUREMENT_ID, C_COLUMN_DUPLICATE, C_COLUMN_LATE,
    C_IMU_WRONG_SIZE, C_IMU_UNSUPPORTED_PROFILE, C_IMU_BAD_VALUE, C_CLOCK_RESETS,
    C_PACKETS_THERMAL_SHUTDOWN, C_PACKETS_SHOT_LIMITING,
    C_COUNT
};
static const char *const COUNTER_NAMES[C_COUNT] = {
    "lidar_packets", "imu_packets", "frames", "imu_samples",
    "frames_incomplete", "columns_missing", "columns_status_invalid",
    "rejected_lidar_wrong_size", "rejected_lidar_wrong_packet_type", "rejected_lidar_wrong_sensor",
    "rejected_column_bad_measurement_id", "rejected_column_duplicate", "rejected_column_late",
    "rejected_imu_wrong_size", "rejected_imu_unsupported_profile", "rejected_imu_bad_value", "clock_resets",
    "packets_thermal_shutdown_alert", "packets_shot_limiting",
};

#define CLOCK_WINDOW_US 10000000LL
#define CLOCK_JUMP_US 1000000LL
#define EPOCH_NS_MIN 1000000000000000000ULL   /* 2001-09-09: below it, time since boot */

struct ouster_driver {
    ouster_meta_t meta;
    ouster_config_t cfg;
    ouster_layout_t L;
    ouster_scan_fn on_scan;
    ouster_imu_fn on_imu;
    void *user;
    int rows, cols, w0, wcount;
    int include_signal;
    double col_period_ns;
    char sensor[80], imu_sensor[96];

    /* frame being assembled */
    int active;
    uint16_t frame_id;
    int ncols_in_window, ncols_total;
    int npending;                   /* columns of the current packet not yet written */
    const uint8_t *pending_px[OUSTER_MAX_PACKET_COLS];
    uint16_t pending_mid[OUSTER_MAX_PACKET_COLS];
    uint8_t *seen;
    uint64_t *ts_ns;
    int64_t last_col_recv;
    int have_published;
    uint16_t last_published;
    portobello_lidar_scan_t scan;

    /* sensor clock -> utime */
    int clock_init;
    int64_t offset_us, window_min_us, window_start;

    uint8_t health;                 /* last thermal_shutdown << 4 | shot_limiting */
    int64_t counters[C_COUNT];
    char last_error[512];
    int64_t error_seq;
};

void ouster_config_default(ouster_config_t *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->which_return = 1;
    cfg->signal = OUSTER_SIGNAL_AUTO;
    cfg->check_sensor_id = 1;
}

static void reject(ouster_driver_t *d, int counter, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void reject(ouster_driver_t *d, int counter, const char *fmt, ...)
{
    d->counters[counter]++;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(d->last_error, sizeof d->last_error, fmt, ap);
    va_end(ap);
    d->error_seq++;
}

ouster_driver_t *ouster_driver_create(const ouster_meta_t *meta, const ouster_config_t *cfg,
                                      ouster_scan_fn on_scan, ouster_imu_fn on_imu, void *user, pb_err_t *err)
{
    if (meta->rows < 1 || meta->rows > OUSTER_MAX_ROWS || meta->cols_per_frame < 1 ||
        meta->cols_per_frame > OUSTER_MAX_COLS || meta->cols_per_packet < 1 || meta->cols_per_packet > meta->cols_per_frame ||
        meta->cols_per_packet > OUSTER_MAX_PACKET_COLS) {
        pb_err_set(err, "metadata: %d rows x %d columns (%d per packet) not supported", meta->rows,
                   meta->cols_per_frame, meta->cols_per_packet);
        return NULL;
    }
    if (cfg->which_return != 1 && cfg->which_return != 2) {
        pb_err_set(err, "return %d: expected 1 or 2", cfg->which_return);
        return NULL;
    }
    const double *B = meta->beam_to_lidar;
    if (B[0] != 1 || B[1] != 0 || B[2] != 0 || B[4] != 0 || B[5] != 1 || B[6] != 0 || B[7] != 0 ||
        B[8] != 0 || B[9] != 0 || B[10] != 1) {
        pb_err_set(err, "metadata: beam_to_lidar_transform with a rotation or a y offset is not supported");
        return NULL;
    }
    ouster_driver_t *d = calloc(1, sizeof *d);
    if (!d) { pb_err_set(err, "out of memory"); return NULL; }
    d->meta = *meta;
    d->cfg = *cfg;
    d->on_scan = on_scan;
    d->on_imu = on_imu;
    d->user = user;
    if (ouster_layout_init(&d->L, meta->profile, meta->rows, meta->cols_per_packet) != 0) {
        pb_err_set(err, "metadata: unsupported profile");
        free(d);
        return NULL;
    }
    d->rows = meta->rows;
    d->cols = meta->cols_per_frame;
    d->w0 = meta->column_window[0];
    int w1 = meta->column_window[1];
    d->wcount = w1 >= d->w0 ? w1 - d->w0 + 1 : d->cols - d->w0 + w1 + 1;
    d->col_period_ns = 1e9 / ((double)meta->frame_rate_hz * d->cols);
    d->include_signal = d->L.has_signal && (cfg->signal == OUSTER_SIGNAL_ON ||
                        (cfg->signal == OUSTER_SIGNAL_AUTO && d->rows * d->cols <= 64 * 1024));
    snprintf(d->sensor, sizeof d->sensor, "%s", meta->prod_line[0] ? meta->prod_line : "Ouster");
    snprintf(d->imu_sensor, sizeof d->imu_sensor, "%s-imu", d->sensor);

    size_t np = (size_t)d->rows * d->cols;
    portobello_lidar_scan_t *s = &d->scan;
    s->sensor = d->sensor;
    s->rows = d->rows;
    s->cols = d->cols;
    s->npixels = (int32_t)np;
    s->range_mm = calloc(np, sizeof *s->range_mm);
    s->reflectivity = calloc(np, 1);
    s->signal = calloc(np, sizeof *s->signal);
    s->near_ir = calloc(np, sizeof *s->near_ir);
    s->nsignal = d->include_signal ? (int32_t)np : 0;
    s->col_offset_us = calloc(d->cols, sizeof *s->col_offset_us);
    s->beam_altitude_rad = calloc(d->rows, sizeof(float));
    s->beam_azimuth_rad = calloc(d->rows, sizeof(float));
    d->seen = calloc(d->cols, 1);
    d->ts_ns = calloc(d->cols, sizeof *d->ts_ns);
    if (!s->range_mm || !s->reflectivity || !s->signal || !s->near_ir || !s->col_offset_us ||
        !s->beam_altitude_rad || !s->beam_azimuth_rad || !d->seen || !d->ts_ns) {
        ouster_driver_destroy(d);
        pb_err_set(err, "out of memory");
        return NULL;
    }
    /* The Ouster beam model in lidar_scan_t's terms: azimuth is subtracted from the
     * encoder angle by Ouster (theta_a = -azimuth), added by lidar_scan_t. */
    for (int r = 0; r < d->rows; r++) {
        s->beam_altitude_rad[r] = (float)(meta->beam_altitude_deg[r] * M_PI / 180.0);
        s->beam_azimuth_rad[r] = (float)(-meta->beam_azimuth_deg[r] * M_PI / 180.0);
    }
    /* beam origin: beam_to_lidar x offset; a z offset (FW 3.x) becomes a translation
     * of the beam frame, and lidar_to_sensor (mm) the rest of lidar_from_beam. */
    s->beam_origin_m = (float)(B[3] / 1000.0);
    const double *T = meta->lidar_to_sensor;
    for (int i = 0; i < 16; i++) s->lidar_from_beam[i] = T[i];
    for (int i = 0; i < 3; i++)
        s->lidar_from_beam[4 * i + 3] = (T[4 * i + 3] + T[4 * i + 2] * B[11]) / 1000.0;
    return d;
}

void ouster_driver_destroy(ouster_driver_t *d)
{
    if (!d) return;
    portobello_lidar_scan_t *s = &d->scan;
    free(s->range_mm); free(s->reflectivity); free(s->signal); free(s->near_ir);
    free(s->col_offset_us); free(s->beam_altitude_rad); free(s->beam_azimuth_rad);
    free(d->seen); free(d->ts_ns);
    free(d);
}

const ouster_layout_t *ouster_driver_layout(const ouster_driver_t *d) { return &d->L; }

int ouster_driver_counters(const ouster_driver_t *d, const char *const **names, const int64_t **values)
{
    *names = COUNTER_NAMES;
    *values = d->counters;
    return C_COUNT;
}

int64_t ouster_driver_counter(const ouster_driver_t *d, const char *name)
{
    for (int i = 0; i < C_COUNT; i++)
        if (strcmp(COUNTER_NAMES[i], name) == 0) return d->counters[i];
    return -1;
}

const char *ouster_driver_last_error(const ouster_driver_t *d, int64_t *seq)
{
    if (seq) *seq = d->error_seq;
    return d->last_error;
}

/* ---------------------------------------------------------------- clock */

/* Feeds one (sensor time, receive time) observation. */
static void clock_observe(ouster_driver_t *d, uint64_t ts_ns, int64_t recv_utime)
{
    if (ts_ns >= EPOCH_NS_MIN) return;
    int64_t delta = recv_utime - (int64_t)(ts_ns / 1000);
    if (!d->clock_init) {
        d->clock_init = 1;
        d->offset_us = d->window_min_us = delta;
        d->window_start = recv_utime;
        return;
    }
    if (delta < d->offset_us - CLOCK_JUMP_US || delta > d->offset_us + CLOCK_JUMP_US) {
        /* sensor rebooted (or the host clock jumped): start over */
        d->counters[C_CLOCK_RESETS]++;
        d->offset_us = d->window_min_us = delta;
        d->window_start = recv_utime;
        return;
    }
    if (delta < d->window_min_us) d->window_min_us = delta;
    /* The offset changes only at window ends, so within a window utime differences are
     * exactly sensor time differences. */
    if (recv_utime - d->window_start >= CLOCK_WINDOW_US) {
        d->offset_us = d->window_min_us;
        d->window_min_us = delta;
        d->window_start = recv_utime;
    }
}

static int64_t clock_utime(const ouster_driver_t *d, uint64_t ts_ns)
{
    if (ts_ns >= EPOCH_NS_MIN) return (int64_t)(ts_ns / 1000);
    return (int64_t)(ts_ns / 1000) + d->offset_us;
}

/* ---------------------------------------------------------------- frames */

static int in_window(const ouster_driver_t *d, int mid)
{
    int k = mid - d->w0;
    if (k < 0) k += d->cols;
    return k < d->wcount;
}

static void fill_pending(ouster_driver_t *d);

static void publish_frame(ouster_driver_t *d, int64_t recv_utime)
{
    fill_pending(d);
    if (!d->active) return;
    portobello_lidar_scan_t *s = &d->scan;
    /* first received column in window order gives the time of column w0 */
    int first = -1;
    for (int k = 0; k < d->cols && first < 0; k++) {
        int c = (d->w0 + k) % d->cols;
        if (d->seen[c]) first = k;
    }
    int cfirst = (d->w0 + first) % d->cols;
    double t0 = (double)d->ts_ns[cfirst] - first * d->col_period_ns;
    uint64_t t0_ns = t0 > 0 ? (uint64_t)llround(t0) : 0;
    for (int c = 0; c < d->cols; c++) {
        double dt = d->seen[c] ? (double)d->ts_ns[c] - (double)t0_ns
                               : ((c - d->w0 + d->cols) % d->cols) * d->col_period_ns;
        double us = dt / 1000.0;   /* a damaged timestamp must not overflow the int32 */
        s->col_offset_us[c] = us > INT32_MAX ? INT32_MAX : us < INT32_MIN ? INT32_MIN : (int32_t)llround(us);
    }
    /* Pixels of columns that did not arrive still hold an older frame: no return. */
    if (d->ncols_total < d->cols)
        for (int c = 0; c < d->cols; c++) {
            if (d->seen[c]) continue;
            for (int r = 0; r < d->rows; r++) {
                size_t i = (size_t)r * d->cols + c;
                s->range_mm[i] = 0; s->reflectivity[i] = 0; s->signal[i] = 0; s->near_ir[i] = 0;
            }
        }
    s->utime = clock_utime(d, t0_ns);
    s->seq = d->frame_id;
    int missing = d->wcount - d->ncols_in_window;
    if (missing > 0) {
        d->counters[C_FRAMES_INCOMPLETE]++;
        d->counters[C_COLUMNS_MISSING] += missing;
    }
    d->counters[C_FRAMES]++;
    if (d->on_scan) d->on_scan(s, recv_utime, d->user);

    memset(d->seen, 0, d->cols);
    d->active = 0;
    d->ncols_in_window = 0;
    d->ncols_total = 0;
    d->have_published = 1;
    d->last_published = d->frame_id;
}

/* Writes the pending columns of a packet into the frame, row by row: a packet's columns
 * are neighbours in the row-major image, so each row's writes share cache lines. This is
 * the hot path (65536 pixels per 64 x 1024 frame): inlined once per profile, so that the
 * field offsets are constants (with run-time offsets it takes 29% longer). */
static inline __attribute__((always_inline)) void fill_rows(ouster_driver_t *d, int n, ouster_pixel_fields_t f)
{
    portobello_lidar_scan_t *s = &d->scan;
    const int cols = d->cols, rows = d->rows;
    const size_t ps = d->L.pixel_size;
    const uint8_t *const *pp = d->pending_px;
    const uint16_t *mid = d->pending_mid;
    uint16_t *sig = (uint16_t *)s->signal, *nir = (uint16_t *)s->near_ir;
    for (int r = 0; r < rows; r++) {
        int32_t *range = s->range_mm + (size_t)r * cols;
        uint8_t *refl = s->reflectivity + (size_t)r * cols;
        uint16_t *sg = sig + (size_t)r * cols, *ni = nir + (size_t)r * cols;
        const size_t o = (size_t)r * ps;
        for (int j = 0; j < n; j++) {
            const uint8_t *px = pp[j] + o;
            int c = mid[j];
            if (f.range_mask) {
                range[c] = (int32_t)(ouster_rd32(px + f.range) & f.range_mask);
                refl[c] = px[f.reflectivity];
                sg[c] = ouster_rd16(px + f.signal);
                ni[c] = ouster_rd16(px + f.near_ir);
            } else {   /* RNG15_RFL8_NIR8: a packed 4-byte pixel */
                range[c] = (int32_t)(ouster_rd16(px) & 0x7FFF) * 8;
                refl[c] = px[2];
                sg[c] = 0;
                ni[c] = (uint16_t)(px[3] * 16);
            }
        }
    }
}

static void fill_pending(ouster_driver_t *d)
{
    const int n = d->npending;
    if (n == 0) return;
    d->npending = 0;
    switch (d->L.profile) {
    case OUSTER_PROFILE_LEGACY: fill_rows(d, n, ouster_pixel_fields(OUSTER_PROFILE_LEGACY, 1)); break;
    case OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16: fill_rows(d, n, ouster_pixel_fields(OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16, 1)); break;
    case OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL:
        if (d->cfg.which_return == 2) fill_rows(d, n, ouster_pixel_fields(OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL, 2));
        else fill_rows(d, n, ouster_pixel_fields(OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL, 1));
        break;
    default: fill_rows(d, n, ouster_pixel_fields(OUSTER_PROFILE_RNG15_RFL8_NIR8, 1)); break;
    }
}

/* A packet of frame fid after last_published: late if it is that frame or up to 3 before it
 * (older ones mean the sensor restarted its count). */
static int is_late(const ouster_driver_t *d, uint16_t fid)
{
    if (!d->have_published) return 0;
    uint16_t behind = (uint16_t)(d->last_published - fid);
    return behind <= 3;
}

static const char *size_guess(int rows_hint, size_t len, char *buf, size_t cap)
{
    static const int rows_list[] = { 16, 32, 64, 128 };
    buf[0] = 0;
    for (int p = OUSTER_PROFILE_LEGACY; p <= OUSTER_PROFILE_RNG15_RFL8_NIR8; p++)
        for (int i = 0; i < 4; i++) {
            ouster_layout_t L;
            ouster_layout_init(&L, (ouster_profile_t)p, rows_list[i], 16);
            if (L.packet_size == len) {
                snprintf(buf, cap, " (the size of %s with %d rows: metadata does not match the sensor?)",
                         ouster_profile_name((ouster_profile_t)p), rows_list[i]);
                return buf;
            }
        }
    (void)rows_hint;
    return buf;
}

void ouster_driver_lidar_packet(ouster_driver_t *d, const uint8_t *buf, size_t len, int64_t recv_utime)
{
    d->counters[C_LIDAR_PACKETS]++;
    int64_t n = d->counters[C_LIDAR_PACKETS];
    const ouster_layout_t *L = &d->L;
    if (len != L->packet_size) {
        char g[160];
        reject(d, C_LIDAR_WRONG_SIZE, "lidar packet %lld: %zu bytes, %s %dx%d per packet expects %zu%s",
               (long long)n, len, ouster_profile_name(L->profile), d->rows, L->cols_per_packet, L->packet_size,
               size_guess(d->rows, len, g, sizeof g));
        return;
    }
    uint16_t pfid = 0;
    if (L->packet_header) {
        ouster_packet_header_t h;
        ouster_packet_header_decode(buf, &h);
        if (h.packet_type != 1) {
            reject(d, C_LIDAR_WRONG_PACKET_TYPE, "lidar packet %lld: packet_type %u, expected 1", (long long)n,
                   h.packet_type);
            return;
        }
        if (d->cfg.check_sensor_id && ((d->meta.init_id && h.init_id != d->meta.init_id) ||
                                       (d->meta.prod_sn_num && h.prod_sn != d->meta.prod_sn_num))) {
            reject(d, C_LIDAR_WRONG_SENSOR, "lidar packet %lld: init_id %u / prod_sn %llu, metadata says %u / %llu",
                   (long long)n, h.init_id, (unsigned long long)h.prod_sn, d->meta.init_id,
                   (unsigned long long)d->meta.prod_sn_num);
            return;
        }
        pfid = h.frame_id;
        /* sensor health carried in every packet: counted, and said once per change */
        if (h.thermal_shutdown) d->counters[C_PACKETS_THERMAL_SHUTDOWN]++;
        if (h.shot_limiting) d->counters[C_PACKETS_SHOT_LIMITING]++;
        uint8_t health = (uint8_t)(h.thermal_shutdown << 4 | h.shot_limiting);
        if (health != d->health) {
            d->health = health;
            if (health) {
                snprintf(d->last_error, sizeof d->last_error,
                         "lidar packet %lld: sensor reports thermal_shutdown %u (countdown %u s), shot_limiting %u "
                         "(countdown %u s)", (long long)n, h.thermal_shutdown, h.countdown_thermal_shutdown,
                         h.shot_limiting, h.countdown_shot_limiting);
                d->error_seq++;
            }
        }
    }
    uint64_t last_ts = 0;
    for (int k = 0; k < L->cols_per_packet; k++) {
        ouster_column_t c;
        ouster_column_decode(L, buf, k, pfid, &c);
        if (!c.valid) { d->counters[C_COLUMNS_STATUS_INVALID]++; continue; }
        if (c.measurement_id >= d->cols) {
            reject(d, C_COLUMN_BAD_MEASUREMENT_ID, "lidar packet %lld column %d: measurement_id %u >= %d columns",
                   (long long)n, k, c.measurement_id, d->cols);
            continue;
        }
        if (d->active && c.frame_id != d->frame_id) {
            /* a column of a frame just before this one arrived late: it must not close this one */
            if ((uint16_t)(d->frame_id - c.frame_id) <= 3) {
                reject(d, C_COLUMN_LATE, "lidar packet %lld column %d: frame %u arrived during frame %u",
                       (long long)n, k, c.frame_id, d->frame_id);
                continue;
            }
            publish_frame(d, recv_utime);
        }
        if (!d->active) {
            if (is_late(d, c.frame_id)) {
                reject(d, C_COLUMN_LATE, "lidar packet %lld column %d: frame %u already published", (long long)n, k,
                       c.frame_id);
                continue;
            }
            d->active = 1;
            d->frame_id = c.frame_id;
        }
        if (d->seen[c.measurement_id]) {
            reject(d, C_COLUMN_DUPLICATE, "lidar packet %lld column %d: measurement_id %u of frame %u seen twice",
                   (long long)n, k, c.measurement_id, c.frame_id);
            continue;
        }
        d->pending_px[d->npending] = c.pixels;
        d->pending_mid[d->npending++] = c.measurement_id;
        d->seen[c.measurement_id] = 1;
        d->ncols_total++;
        d->ts_ns[c.measurement_id] = c.timestamp_ns;
        d->last_col_recv = recv_utime;
        last_ts = c.timestamp_ns;
        if (in_window(d, c.measurement_id) && ++d->ncols_in_window == d->wcount) {
            clock_observe(d, last_ts, recv_utime);
            last_ts = 0;
            publish_frame(d, recv_utime);
        }
    }
    fill_pending(d);
    if (last_ts) clock_observe(d, last_ts, recv_utime);
}

void ouster_driver_imu_packet(ouster_driver_t *d, const uint8_t *buf, size_t len, int64_t recv_utime)
{
    d->counters[C_IMU_PACKETS]++;
    int64_t n = d->counters[C_IMU_PACKETS];
    if (!d->meta.imu_profile_legacy) {
        reject(d, C_IMU_UNSUPPORTED_PROFILE, "IMU packet %lld: only the LEGACY IMU profile is decoded", (long long)n);
        return;
    }
    ouster_imu_packet_t p;
    if (ouster_imu_decode(buf, len, &p) != 0) {
        reject(d, C_IMU_WRONG_SIZE, "IMU packet %lld: %zu bytes, expected %d", (long long)n, len, OUSTER_IMU_LEGACY_SIZE);
        return;
    }
    for (int i = 0; i < 3; i++)
        if (!isfinite(p.accel_g[i]) || !isfinite(p.gyro_dps[i]) || fabsf(p.accel_g[i]) > 1000 ||
            fabsf(p.gyro_dps[i]) > 1e5) {
            reject(d, C_IMU_BAD_VALUE, "IMU packet %lld: accel or gyro value not finite or out of range", (long long)n);
            return;
        }
    clock_observe(d, p.sys_ts_ns, recv_utime);
    portobello_imu_t m = { .utime = clock_utime(d, p.accel_ts_ns), .sensor = d->imu_sensor };
    for (int i = 0; i < 3; i++) {
        m.accel[i] = p.accel_g[i] * OUSTER_G;
        m.gyro[i] = p.gyro_dps[i] * (M_PI / 180.0);
    }
    d->counters[C_IMU_SAMPLES]++;
    if (d->on_imu) d->on_imu(&m, recv_utime, d->user);
}

void ouster_driver_flush(ouster_driver_t *d, int64_t now_utime) { publish_frame(d, now_utime); }

void ouster_driver_tick(ouster_driver_t *d, int64_t now_utime)
{
    int64_t period_us = 1000000 / (d->meta.frame_rate_hz > 0 ? d->meta.frame_rate_hz : 10);
    if (d->active && now_utime - d->last_col_recv > period_us * 3 / 2) publish_frame(d, now_utime);
}
