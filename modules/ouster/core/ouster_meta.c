/* Ouster metadata JSON -> ouster_meta_t (flat and nested layouts, SDK defaults). */
#include "ouster_meta.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

static const char *const profile_names[] = {
    [OUSTER_PROFILE_UNKNOWN] = "UNKNOWN",
    [OUSTER_PROFILE_LEGACY] = "LEGACY",
    [OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16] = "RNG19_RFL8_SIG16_NIR16",
    [OUSTER_PROFILE_RNG19_RFL8_SIG16_NIR16_DUAL] = "RNG19_RFL8_SIG16_NIR16_DUAL",
    [OUSTER_PROFILE_RNG15_RFL8_NIR8] = "RNG15_RFL8_NIR8",
};

const char *ouster_profile_name(ouster_profile_t p)
{
    return (p >= 0 && p <= OUSTER_PROFILE_RNG15_RFL8_NIR8) ? profile_names[p] : "UNKNOWN";
}

ouster_profile_t ouster_profile_of_name(const char *name)
{
    for (int p = OUSTER_PROFILE_LEGACY; p <= OUSTER_PROFILE_RNG15_RFL8_NIR8; p++)
        if (strcmp(name, profile_names[p]) == 0) return (ouster_profile_t)p;
    return OUSTER_PROFILE_UNKNOWN;
}

/* The first of `sections` (objects under the root; NULL = the root itself) that holds
 * key. A section that is not an object (FW 1.12 writes "error: Command not recognized."
 * for lidar_data_format) is skipped. */
static const cJSON *find(const cJSON *root, const char *key, const char *const *sections)
{
    for (; *sections; sections++) {
        const cJSON *sec = (*sections)[0] ? cJSON_GetObjectItemCaseSensitive(root, *sections) : root;
        if (!cJSON_IsObject(sec)) continue;
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(sec, key);
        if (v && !cJSON_IsNull(v)) return v;
    }
    return NULL;
}

static const char *const S_BEAM[] = { "beam_intrinsics", "", NULL };
static const char *const S_LIDAR[] = { "lidar_intrinsics", "", NULL };
static const char *const S_IMU[] = { "imu_intrinsics", "", NULL };
static const char *const S_FORMAT[] = { "lidar_data_format", "data_format", NULL };
static const char *const S_PROFILE[] = { "lidar_data_format", "data_format", "config_params", "", NULL };
static const char *const S_CONFIG[] = { "config_params", "", NULL };
static const char *const S_INFO[] = { "sensor_info", "", NULL };

static void note_default(ouster_meta_t *m, const char *field)
{
    size_t n = strlen(m->defaults);
    snprintf(m->defaults + n, sizeof m->defaults - n, "%s%s", n ? "," : "", field);
}

/* A JSON array of exactly `want` finite numbers (want < 0: any count up to cap).
 * Returns the count, or -1 with err set. */
static int read_numbers(const cJSON *v, const char *name, double *out, int want, int cap, pb_err_t *err)
{
    if (!cJSON_IsArray(v)) return pb_err_set(err, "%s: expected an array of numbers", name);
    int n = cJSON_GetArraySize(v);
    if (want >= 0 && n != want) return pb_err_set(err, "%s: %d values, expected %d", name, n, want);
    if (n > cap) return pb_err_set(err, "%s: %d values, at most %d supported", name, n, cap);
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, v) {
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble))
            return pb_err_set(err, "%s[%d]: not a finite number", name, i);
        out[i++] = e->valuedouble;
    }
    return n;
}

static int read_int(const cJSON *v, const char *name, long lo, long hi, long *out, pb_err_t *err)
{
    if (!cJSON_IsNumber(v) || v->valuedouble != floor(v->valuedouble) || v->valuedouble < lo || v->valuedouble > hi)
        return pb_err_set(err, "%s: expected an integer in [%ld, %ld]", name, lo, hi);
    *out = (long)v->valuedouble;
    return 0;
}

static void copy_string(const cJSON *v, char *dst, size_t cap)
{
    if (cJSON_IsString(v)) snprintf(dst, cap, "%s", v->valuestring);
}

static int read_transform(const cJSON *root, const char *key, const char *const *sections, double *out,
                          const double *dflt, ouster_meta_t *m, pb_err_t *err)
{
    const cJSON *v = find(root, key, sections);
    if (!v) {
        memcpy(out, dflt, 16 * sizeof *out);
        note_default(m, key);
        return 0;
    }
    return read_numbers(v, key, out, 16, 16, err) < 0 ? -1 : 0;
}

/* Defaults from ouster-sdk (sensor_info defaults for gen-1 OS1 sensors without the field). */
static const double DEFAULT_LIDAR_TO_SENSOR[16] = { -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 36.18, 0, 0, 0, 1 };
static const double DEFAULT_IMU_TO_SENSOR[16] = { 1, 0, 0, 6.253, 0, 1, 0, -11.775, 0, 0, 1, 7.645, 0, 0, 0, 1 };

static double default_beam_origin_mm(const char *prod_line)
{
    if (strncmp(prod_line, "OS-0-", 5) == 0) return 27.67;
    if (strncmp(prod_line, "OS-1-", 5) == 0) return 15.806;
    if (strncmp(prod_line, "OS-2-", 5) == 0) return 13.762;
    return 12.163;  /* gen 1 */
}

static int parse_root(const cJSON *root, ouster_meta_t *m, pb_err_t *err)
{
    if (!cJSON_IsObject(root)) return pb_err_set(err, "top level is not a JSON object");
    const cJSON *v;
    long l;

    copy_string(find(root, "prod_line", S_INFO), m->prod_line, sizeof m->prod_line);
    copy_string(find(root, "prod_sn", S_INFO), m->prod_sn, sizeof m->prod_sn);
    copy_string(find(root, "build_rev", S_INFO), m->fw_rev, sizeof m->fw_rev);
    if (m->prod_sn[0]) {
        char *end;
        errno = 0;
        unsigned long long sn = strtoull(m->prod_sn, &end, 10);
        if (*end == 0 && errno == 0) m->prod_sn_num = sn;
    }
    if ((v = find(root, "initialization_id", S_INFO))) {
        if (read_int(v, "initialization_id", 0, 0xFFFFFF, &l, err)) return -1;
        m->init_id = (uint32_t)l;
    }

    /* lidar_mode "COLSxHZ" */
    int mode_cols = 0;
    m->frame_rate_hz = 10;
    if ((v = find(root, "lidar_mode", S_CONFIG))) {
        int hz = 0, used = 0;
        if (!cJSON_IsString(v) || sscanf(v->valuestring, "%dx%d%n", &mode_cols, &hz, &used) != 2 ||
            v->valuestring[used] != 0 || mode_cols < 1 || mode_cols > OUSTER_MAX_COLS || hz < 1 || hz > 100)
            return pb_err_set(err, "lidar_mode: expected \"COLUMNSxHZ\" such as \"1024x10\"");
        snprintf(m->lidar_mode, sizeof m->lidar_mode, "%s", v->valuestring);
        m->frame_rate_hz = hz;
    } else {
        note_default(m, "lidar_mode");
    }

    /* beam intrinsics: required */
    int rows_from_format = 0;
    if ((v = find(root, "pixels_per_column", S_FORMAT))) {
        if (read_int(v, "pixels_per_column", 1, OUSTER_MAX_ROWS, &l, err)) return -1;
        rows_from_format = (int)l;
    }
    v = find(root, "beam_altitude_angles", S_BEAM);
    if (!v) return pb_err_set(err, "beam_altitude_angles: missing (no default: the beam calibration is per sensor)");
    int nalt = read_numbers(v, "beam_altitude_angles", m->beam_altitude_deg, rows_from_format ? rows_from_format : -1,
                            OUSTER_MAX_ROWS, err);
    if (nalt < 0) return -1;
    if (nalt == 0) return pb_err_set(err, "beam_altitude_angles: empty");
    m->rows = nalt;
    if (!rows_from_format) note_default(m, "pixels_per_column");
    v = find(root, "beam_azimuth_angles", S_BEAM);
    if (!v) return pb_err_set(err, "beam_azimuth_angles: missing (no default: the beam calibration is per sensor)");
    if (read_numbers(v, "beam_azimuth_angles", m->beam_azimuth_deg, m->rows, OUSTER_MAX_ROWS, err) < 0) return -1;

    /* data format: columns, packet layout, pixel shift */
    if ((v = find(root, "columns_per_frame", S_FORMAT))) {
        if (read_int(v, "columns_per_frame", 1, OUSTER_MAX_COLS, &l, err)) return -1;
        m->cols_per_frame = (int)l;
    } else if (mode_cols) {
        m->cols_per_frame = mode_cols;
        note_default(m, "columns_per_frame");
    } else {
        return pb_err_set(err, "columns_per_frame: missing, and no lidar_mode to take it from");
    }
    if ((v = find(root, "columns_per_packet", S_FORMAT))) {
        if (read_int(v, "columns_per_packet", 1, m->cols_per_frame, &l, err)) return -1;
        m->cols_per_packet = (int)l;
    } else {
        m->cols_per_packet = m->cols_per_frame < 16 ? m->cols_per_frame : 16;
        note_default(m, "columns_per_packet");
    }
    m->column_window[0] = 0;
    m->column_window[1] = m->cols_per_frame - 1;
    if ((v = find(root, "column_window", S_FORMAT))) {
        double w[2];
        if (read_numbers(v, "column_window", w, 2, 2, err) < 0) return -1;
        if (w[0] != floor(w[0]) || w[1] != floor(w[1]) || w[0] < 0 || w[1] < 0 ||
            w[0] >= m->cols_per_frame || w[1] >= m->cols_per_frame)
            return pb_err_set(err, "column_window: [%g, %g] outside 0..%d", w[0], w[1], m->cols_per_frame - 1);
        m->column_window[0] = (int)w[0];
        m->column_window[1] = (int)w[1];
    } else {
        note_default(m, "column_window");
    }
    if ((v = find(root, "pixel_shift_by_row", S_FORMAT))) {
        double s[OUSTER_MAX_ROWS];
        if (read_numbers(v, "pixel_shift_by_row", s, m->rows, OUSTER_MAX_ROWS, err) < 0) return -1;
        for (int r = 0; r < m->rows; r++) {
            if (s[r] != floor(s[r]) || fabs(s[r]) >= m->cols_per_frame)
                return pb_err_set(err, "pixel_shift_by_row[%d]: %g is not a column shift", r, s[r]);
            m->pixel_shift_by_row[r] = (int)s[r];
        }
    } else {
        /* ouster-sdk default_data_format: {3k, 2k, k, 0} repeated, k = 6 per 1024 columns */
        int k = m->cols_per_frame * 6 / 1024;
        for (int r = 0; r < m->rows; r++) m->pixel_shift_by_row[r] = k * (3 - r % 4);
        note_default(m, "pixel_shift_by_row");
    }

    /* UDP profiles */
    m->profile = OUSTER_PROFILE_LEGACY;
    if ((v = find(root, "udp_profile_lidar", S_PROFILE))) {
        if (!cJSON_IsString(v)) return pb_err_set(err, "udp_profile_lidar: expected a string");
        m->profile = ouster_profile_of_name(v->valuestring);
        if (m->profile == OUSTER_PROFILE_UNKNOWN)
            return pb_err_set(err, "udp_profile_lidar: '%s' is not supported (LEGACY, RNG19_RFL8_SIG16_NIR16, "
                              "RNG19_RFL8_SIG16_NIR16_DUAL, RNG15_RFL8_NIR8)", v->valuestring);
    } else {
        note_default(m, "udp_profile_lidar");
    }
    m->imu_profile_legacy = 1;
    if ((v = find(root, "udp_profile_imu", S_PROFILE)))
        m->imu_profile_legacy = cJSON_IsString(v) && strcmp(v->valuestring, "LEGACY") == 0;
    if ((v = find(root, "header_type", S_PROFILE)) &&
        !(cJSON_IsString(v) && strcmp(v->valuestring, "STANDARD") == 0))
        return pb_err_set(err, "header_type: only STANDARD packet headers are supported");

    if ((v = find(root, "udp_port_lidar", S_CONFIG))) {
        if (read_int(v, "udp_port_lidar", 0, 65535, &l, err)) return -1;
        m->udp_port_lidar = (int)l;
    }
    if ((v = find(root, "udp_port_imu", S_CONFIG))) {
        if (read_int(v, "udp_port_imu", 0, 65535, &l, err)) return -1;
        m->udp_port_imu = (int)l;
    }

    /* geometry */
    if ((v = find(root, "lidar_origin_to_beam_origin_mm", S_BEAM))) {
        if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble) || fabs(v->valuedouble) > 1000)
            return pb_err_set(err, "lidar_origin_to_beam_origin_mm: expected a number of mm");
        m->lidar_origin_to_beam_origin_mm = v->valuedouble;
    } else {
        m->lidar_origin_to_beam_origin_mm = default_beam_origin_mm(m->prod_line);
        note_default(m, "lidar_origin_to_beam_origin_mm");
    }
    double dflt_beam[16] = { 1, 0, 0, m->lidar_origin_to_beam_origin_mm, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 };
    if (read_transform(root, "beam_to_lidar_transform", S_BEAM, m->beam_to_lidar, dflt_beam, m, err)) return -1;
    if (read_transform(root, "lidar_to_sensor_transform", S_LIDAR, m->lidar_to_sensor, DEFAULT_LIDAR_TO_SENSOR, m, err))
        return -1;
    if (read_transform(root, "imu_to_sensor_transform", S_IMU, m->imu_to_sensor, DEFAULT_IMU_TO_SENSOR, m, err))
        return -1;
    return 0;
}

int ouster_meta_parse(const char *json, size_t len, ouster_meta_t *m, pb_err_t *err)
{
    memset(m, 0, sizeof *m);
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(json, len, &end, 0);
    if (!root) {
        size_t at = end && end >= json && end <= json + len ? (size_t)(end - json) : 0;
        int line = 1;
        for (size_t i = 0; i < at; i++) line += json[i] == '\n';
        return pb_err_set(err, "line %d (byte %zu): not valid JSON", line, at);
    }
    int rc = parse_root(root, m, err);
    cJSON_Delete(root);
    return rc;
}

int ouster_meta_load(const char *path, ouster_meta_t *m, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) return pb_err_set(err, "%s: %s", path, strerror(errno));
    char *buf = NULL;
    size_t len = 0, cap = 0;
    for (;;) {
        if (len == cap) {
            if (cap >= (16u << 20)) { fclose(f); free(buf); return pb_err_set(err, "%s: larger than 16 MB", path); }
            cap = cap ? cap * 2 : 65536;
            char *nb = realloc(buf, cap);
            if (!nb) { fclose(f); free(buf); return pb_err_set(err, "%s: out of memory", path); }
            buf = nb;
        }
        size_t got = fread(buf + len, 1, cap - len, f);
        len += got;
        if (got == 0) break;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) { free(buf); return pb_err_set(err, "%s: read error", path); }
    int rc = ouster_meta_parse(buf, len, m, err);
    free(buf);
    if (rc) pb_err_prefix(err, "%s", path);
    return rc;
}
