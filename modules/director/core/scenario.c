/* scenario: the strict reader of scenario files (format in docs/scenarios.md). */
#include "scenario.h"

#include <math.h>
#include <stdio.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "pb_config.h"

#define DEG (M_PI / 180.0)

static int fail(pb_err_t *err, const pb_cfg_node_t *n, const char *fmt, const char *a, const char *b)
{
    char what[600];
    snprintf(what, sizeof what, fmt, a ? a : "", b ? b : "");
    return pb_err_set(err, "%s:%d: %s", pb_node_file(n), pb_node_line(n), what);
}

/* Line of key `key` in map n, or of n itself. */
static const pb_cfg_node_t *at_key(const pb_cfg_node_t *n, const char *key)
{
    const pb_cfg_node_t *v = pb_node_get(n, key);
    return v ? v : n;
}

static int check_id(const pb_cfg_node_t *n, const char *id, pb_err_t *err)
{
    if (!id[0]) return fail(err, at_key(n, "id"), "id: empty", 0, 0);
    for (const char *p = id; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') || *p == '_' || *p == '-' || *p == '.'))
            return fail(err, at_key(n, "id"), "id '%s': only letters, digits, '_', '-' and '.'", id, 0);
    return 0;
}

/* Asset and animation names travel in AGENTS and the state file: one word, id characters. */
static int check_name(const pb_cfg_node_t *n, const char *key, const char *name, pb_err_t *err)
{
    if (!name[0]) return fail(err, at_key(n, key), "%s: empty", key, 0);
    for (const char *p = name; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') || *p == '_' || *p == '-' || *p == '.'))
            return fail(err, at_key(n, key), "%s '%s': one word of letters, digits, '_', '-' and '.'", key, name);
    return 0;
}

static int finite_all(const double *v, int n)
{
    for (int i = 0; i < n; i++) if (!isfinite(v[i])) return 0;
    return 1;
}

/* A list node (may be absent: count 0). */
static int list_of(const pb_cfg_node_t *n, const char *what, pb_err_t *err)
{
    if (!n) return 0;
    if (pb_node_kind(n) != PB_NODE_LIST) return fail(err, n, "%s: expected a list", what, 0);
    return 0;
}

/* ---------------------------------------------------------------- volumes */
static int read_volume(const pb_cfg_node_t *n, sc_volume_t *v, pb_err_t *err)
{
    struct { char id[SC_ID_LEN], type[16]; double center[2], yaw_deg, size[3], radius, height, z0, z[2]; const pb_cfg_node_t *points; } f;
    memset(&f, 0, sizeof f);
    f.height = 3.0; f.z[0] = 0; f.z[1] = 3.0;
#define F(k, t, m, l, r) { k, t, offsetof(typeof(f), m), l, r }
    const pb_cfg_field_t fields[] = {
        F("id", PB_CFG_STRING, id, SC_ID_LEN, 1), F("type", PB_CFG_STRING, type, 16, 1),
        F("center", PB_CFG_DOUBLES, center, 2, 0), F("yaw_deg", PB_CFG_DOUBLE, yaw_deg, 0, 0),
        F("size", PB_CFG_DOUBLES, size, 3, 0), F("radius", PB_CFG_DOUBLE, radius, 0, 0),
        F("height", PB_CFG_DOUBLE, height, 0, 0), F("z0", PB_CFG_DOUBLE, z0, 0, 0),
        F("z", PB_CFG_DOUBLES, z, 2, 0), F("points", PB_CFG_NODE, points, 0, 0), PB_CFG_END };
#undef F
    if (pb_cfg_read(n, fields, &f, err) || check_id(n, f.id, err)) return -1;
    memset(v, 0, sizeof *v);
    strcpy(v->id, f.id);
    v->line = pb_node_line(n);
    const char *allowed;
    if (!strcmp(f.type, "box")) { v->type = SC_VOL_BOX; allowed = "id type center yaw_deg size z0"; }
    else if (!strcmp(f.type, "cylinder")) { v->type = SC_VOL_CYLINDER; allowed = "id type center radius height z0"; }
    else if (!strcmp(f.type, "prism")) { v->type = SC_VOL_PRISM; allowed = "id type points z"; }
    else return fail(err, at_key(n, "type"), "volume type '%s': expected box, cylinder or prism", f.type, 0);
    for (int i = 0; i < pb_node_count(n); i++) {
        char key[40];
        snprintf(key, sizeof key, " %s ", pb_node_key(n, i));
        char al[80];
        snprintf(al, sizeof al, " %s ", allowed);
        if (!strstr(al, key)) return fail(err, pb_node_at(n, i), "key '%s' does not apply to a %s volume", pb_node_key(n, i), f.type);
    }
    if (v->type == SC_VOL_BOX) {
        if (!pb_node_get(n, "center") || !pb_node_get(n, "size")) return fail(err, n, "box volume '%s': needs center and size", f.id, 0);
        if (!(f.size[0] > 0 && f.size[1] > 0 && f.size[2] > 0) || !finite_all(f.size, 3) || !finite_all(f.center, 2))
            return fail(err, at_key(n, "size"), "box volume '%s': size must be three positive lengths", f.id, 0);
        memcpy(v->center, f.center, sizeof v->center);
        memcpy(v->size, f.size, sizeof v->size);
        v->yaw = f.yaw_deg * DEG;
        v->z[0] = f.z0; v->z[1] = f.z0 + f.size[2];
        memcpy(v->bound_c, f.center, sizeof v->bound_c);
        v->bound_r = 0.5 * hypot(f.size[0], f.size[1]);
    } else if (v->type == SC_VOL_CYLINDER) {
        if (!pb_node_get(n, "center") || !pb_node_get(n, "radius")) return fail(err, n, "cylinder volume '%s': needs center and radius", f.id, 0);
        if (!(f.radius > 0 && f.height > 0) || !isfinite(f.radius) || !isfinite(f.height) || !finite_all(f.center, 2))
            return fail(err, at_key(n, "radius"), "cylinder volume '%s': radius and height must be positive", f.id, 0);
        memcpy(v->center, f.center, sizeof v->center);
        v->radius = f.radius;
        v->z[0] = f.z0; v->z[1] = f.z0 + f.height;
        memcpy(v->bound_c, f.center, sizeof v->bound_c);
        v->bound_r = f.radius;
    } else {
        if (!f.points || pb_node_kind(f.points) != PB_NODE_LIST || pb_node_count(f.points) < 3 || pb_node_count(f.points) > SC_MAX_PRISM_PTS)
            return fail(err, f.points ? f.points : n, "prism volume '%s': points: a list of 3 to 16 [x, y]", f.id, 0);
        if (!(f.z[1] > f.z[0]) || !finite_all(f.z, 2)) return fail(err, at_key(n, "z"), "prism volume '%s': z: [bottom, top] with top > bottom", f.id, 0);
        v->npts = pb_node_count(f.points);
        for (int i = 0; i < v->npts; i++) {
            if (pb_node_doubles(pb_node_at(f.points, i), "points", v->pts[i], 2, err)) return -1;
            if (!finite_all(v->pts[i], 2)) return fail(err, pb_node_at(f.points, i), "prism volume '%s': point is not finite", f.id, 0);
        }
        /* libccd needs a convex shape: every turn has the same sign, none zero. */
        int sign = 0;
        for (int i = 0; i < v->npts; i++) {
            const double *a = v->pts[i], *b = v->pts[(i + 1) % v->npts], *c = v->pts[(i + 2) % v->npts];
            double cr = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
            int sg = cr > 1e-9 ? 1 : cr < -1e-9 ? -1 : 0;
            if (!sg || (sign && sg != sign))
                return fail(err, pb_node_at(f.points, (i + 1) % v->npts), "prism volume '%s': the polygon is not strictly convex at this point (split it into convex volumes)", f.id, 0);
            sign = sg;
        }
        v->z[0] = f.z[0]; v->z[1] = f.z[1];
        for (int i = 0; i < v->npts; i++) { v->bound_c[0] += v->pts[i][0] / v->npts; v->bound_c[1] += v->pts[i][1] / v->npts; }
        for (int i = 0; i < v->npts; i++) v->bound_r = fmax(v->bound_r, hypot(v->pts[i][0] - v->bound_c[0], v->pts[i][1] - v->bound_c[1]));
    }
    return 0;
}

/* ---------------------------------------------------------------- agents */
static int read_agent(const pb_cfg_node_t *n, sc_agent_t *a, pb_err_t *err)
{
    struct { char id[SC_ID_LEN], kind[16], model[SC_ID_LEN]; double start[2], yaw_deg, radius, height, size[3]; } f;
    memset(&f, 0, sizeof f);
    f.radius = 0.3; f.height = 1.8;
#define F(k, t, m, l, r) { k, t, offsetof(typeof(f), m), l, r }
    const pb_cfg_field_t fields[] = {
        F("id", PB_CFG_STRING, id, SC_ID_LEN, 1), F("kind", PB_CFG_STRING, kind, 16, 1),
        F("model", PB_CFG_STRING, model, SC_ID_LEN, 1), F("start", PB_CFG_DOUBLES, start, 2, 1),
        F("yaw_deg", PB_CFG_DOUBLE, yaw_deg, 0, 0), F("radius", PB_CFG_DOUBLE, radius, 0, 0),
        F("height", PB_CFG_DOUBLE, height, 0, 0), F("size", PB_CFG_DOUBLES, size, 3, 0), PB_CFG_END };
#undef F
    if (pb_cfg_read(n, fields, &f, err) || check_id(n, f.id, err) || check_name(n, "model", f.model, err)) return -1;
    static const char *kinds[] = { "pedestrian", "cyclist", "vehicle", "object" };
    int k = -1;
    for (int i = 0; i < 4; i++) if (!strcmp(f.kind, kinds[i])) k = i;
    if (k < 0) return fail(err, at_key(n, "kind"), "agent kind '%s': expected pedestrian, cyclist, vehicle or object", f.kind, 0);
    if (!finite_all(f.start, 2) || !isfinite(f.yaw_deg)) return fail(err, at_key(n, "start"), "agent '%s': start is not finite", f.id, 0);
    memset(a, 0, sizeof *a);
    strcpy(a->id, f.id); strcpy(a->kind, f.kind); strcpy(a->model, f.model);
    a->line = pb_node_line(n);
    memcpy(a->xy, f.start, sizeof a->xy);
    a->yaw = f.yaw_deg * DEG;
    if (pb_node_get(n, "size")) {
        if (pb_node_get(n, "radius") || pb_node_get(n, "height"))
            return fail(err, at_key(n, "size"), "agent '%s': give either size (a box) or radius and height (a cylinder)", f.id, 0);
        if (!(f.size[0] > 0 && f.size[1] > 0 && f.size[2] > 0) || !finite_all(f.size, 3))
            return fail(err, at_key(n, "size"), "agent '%s': size must be three positive lengths", f.id, 0);
        a->shape = SC_SHAPE_BOX;
        memcpy(a->size, f.size, sizeof a->size);
    } else {
        if (!(f.radius > 0 && f.radius < 10 && f.height > 0 && f.height < 20))
            return fail(err, at_key(n, "radius"), "agent '%s': radius in (0, 10) m and height in (0, 20) m", f.id, 0);
        a->shape = SC_SHAPE_CYLINDER;
        a->radius = f.radius; a->height = f.height;
    }
    return 0;
}

static int find_stop(const sc_scenario_t *sc, const char *id)
{
    for (int i = 0; i < sc->nstops; i++) if (!strcmp(sc->stops[i].id, id)) return i;
    return -1;
}

static int unknown_id(pb_err_t *err, const pb_cfg_node_t *n, const char *what, const char *id)
{
    char w[200];
    snprintf(w, sizeof w, "unknown %s", what);
    return pb_err_set(err, "%s:%d: %s '%s'", pb_node_file(n), pb_node_line(n), w, id);
}

/* ---------------------------------------------------------------- behaviours */
static int read_behaviour(const pb_cfg_node_t *n, sc_scenario_t *sc, sc_behaviour_t *b, pb_err_t *err)
{
    struct { char id[SC_ID_LEN], agent[SC_ID_LEN]; const pb_cfg_node_t *path, *sync; } f;
    memset(&f, 0, sizeof f);
    const pb_cfg_field_t fields[] = {
        { "id", PB_CFG_STRING, offsetof(typeof(f), id), SC_ID_LEN, 1 },
        { "agent", PB_CFG_STRING, offsetof(typeof(f), agent), SC_ID_LEN, 1 },
        { "path", PB_CFG_NODE, offsetof(typeof(f), path), 0, 1 },
        { "sync", PB_CFG_NODE, offsetof(typeof(f), sync), 0, 0 }, PB_CFG_END };
    if (pb_cfg_read(n, fields, &f, err) || check_id(n, f.id, err)) return -1;
    strcpy(b->id, f.id);
    b->line = pb_node_line(n);
    b->agent = sc_find_agent(sc, f.agent);
    if (b->agent < 0) return unknown_id(err, at_key(n, "agent"), "agent", f.agent);
    if (pb_node_kind(f.path) != PB_NODE_LIST || pb_node_count(f.path) < 1)
        return fail(err, f.path, "behaviour '%s': path: a list of at least one waypoint", f.id, 0);
    b->npts = pb_node_count(f.path);
    b->pts = calloc(b->npts, sizeof *b->pts);
    for (int i = 0; i < b->npts; i++) {
        const pb_cfg_node_t *wn = pb_node_at(f.path, i);
        sc_waypoint_t *w = &b->pts[i];
        w->speed = 1.4;
        strcpy(w->gesture, "idle");
        const pb_cfg_field_t wf[] = {
            { "to", PB_CFG_DOUBLES, offsetof(sc_waypoint_t, xy), 2, 1 },
            { "speed", PB_CFG_DOUBLE, offsetof(sc_waypoint_t, speed), 0, 0 },
            { "wait_s", PB_CFG_DOUBLE, offsetof(sc_waypoint_t, wait_s), 0, 0 },
            { "gesture", PB_CFG_STRING, offsetof(sc_waypoint_t, gesture), SC_ID_LEN, 0 }, PB_CFG_END };
        if (pb_cfg_read(wn, wf, w, err) || check_name(wn, "gesture", w->gesture, err)) return -1;
        w->line = pb_node_line(wn);
        if (!finite_all(w->xy, 2)) return fail(err, wn, "waypoint: 'to' is not finite", 0, 0);
        if (!(w->speed > 0.05 && w->speed <= 30)) return fail(err, at_key(wn, "speed"), "waypoint speed: expected 0.05 to 30 m/s", 0, 0);
        if (!(w->wait_s >= 0 && w->wait_s <= 3600)) return fail(err, at_key(wn, "wait_s"), "waypoint wait_s: expected 0 to 3600 s", 0, 0);
    }
    b->sync_mark = -1; b->sync_stop = -1;
    if (f.sync) {
        struct { long mark; char stop_line[32]; double speed_min, speed_max, decel, ease; } s = { -1, "", 0.8, 1.8, 2.0, 0.2 };
        const pb_cfg_field_t sf[] = {
            { "mark", PB_CFG_INT, offsetof(typeof(s), mark), 0, 1 },
            { "stop_line", PB_CFG_STRING, offsetof(typeof(s), stop_line), 32, 1 },
            { "speed_min", PB_CFG_DOUBLE, offsetof(typeof(s), speed_min), 0, 0 },
            { "speed_max", PB_CFG_DOUBLE, offsetof(typeof(s), speed_max), 0, 0 },
            { "decel", PB_CFG_DOUBLE, offsetof(typeof(s), decel), 0, 0 },
            { "ease_s", PB_CFG_DOUBLE, offsetof(typeof(s), ease), 0, 0 }, PB_CFG_END };
        if (pb_cfg_read(f.sync, sf, &s, err)) return -1;
        if (s.mark < 0 || s.mark >= b->npts)
            return fail(err, at_key(f.sync, "mark"), "sync mark: expected a waypoint index of this path (0 = first)", 0, 0);
        b->sync_stop = find_stop(sc, s.stop_line);
        if (b->sync_stop < 0) return unknown_id(err, at_key(f.sync, "stop_line"), "stop line (not in the site's route)", s.stop_line);
        if (!(s.speed_min >= 0.1 && s.speed_max >= s.speed_min && s.speed_max <= 15))
            return fail(err, f.sync, "sync: expected 0.1 <= speed_min <= speed_max <= 15 m/s", 0, 0);
        if (!(s.decel >= 0.3 && s.decel <= 10)) return fail(err, at_key(f.sync, "decel"), "sync decel: expected 0.3 to 10 m/s^2", 0, 0);
        if (!(s.ease >= 0 && s.ease <= 3)) return fail(err, at_key(f.sync, "ease_s"), "sync ease_s: expected 0 to 3 s", 0, 0);
        b->sync = 1;
        b->sync_ease = s.ease;
        b->sync_mark = (int)s.mark;
        b->speed_min = s.speed_min; b->speed_max = s.speed_max; b->sync_decel = s.decel;
    }
    return 0;
}

/* ---------------------------------------------------------------- conditions */
static const char *const COND_NAMES[] = { "enter", "distance", "time_to_arrival", "speed", "standstill", "after", "input", "time" };
static const char *const COND_KEYS[] = {
    "volume", "point stop_line below above", "point stop_line below", "below above", "duration_s", "trigger elapsed_s",
    "input", "above" };

static int read_cond(const pb_cfg_node_t *n, sc_scenario_t *sc, int group, sc_cond_t *c, pb_err_t *err)
{
    struct { char type[24], volume[SC_ID_LEN], stop_line[32], trigger[SC_ID_LEN], input[32], edge[24];
             double point[2], below, above, duration_s, elapsed_s, delay_s; } f;
    memset(&f, 0, sizeof f);
    strcpy(f.edge, "none");
#define F(k, t, m, l) { k, t, offsetof(typeof(f), m), l, 0 }
    const pb_cfg_field_t fields[] = {
        F("type", PB_CFG_STRING, type, 24), F("volume", PB_CFG_STRING, volume, SC_ID_LEN),
        F("stop_line", PB_CFG_STRING, stop_line, 32), F("trigger", PB_CFG_STRING, trigger, SC_ID_LEN),
        F("input", PB_CFG_STRING, input, 32), F("edge", PB_CFG_STRING, edge, 24), F("point", PB_CFG_DOUBLES, point, 2),
        F("below", PB_CFG_DOUBLE, below, 0), F("above", PB_CFG_DOUBLE, above, 0), F("duration_s", PB_CFG_DOUBLE, duration_s, 0),
        F("elapsed_s", PB_CFG_DOUBLE, elapsed_s, 0), F("delay_s", PB_CFG_DOUBLE, delay_s, 0), PB_CFG_END };
#undef F
    if (pb_cfg_read(n, fields, &f, err)) return -1;
    memset(c, 0, sizeof *c);
    c->line = pb_node_line(n);
    c->group = group;
    c->stop_line = -1; c->volume = -1; c->after_trigger = -1;
    if (!pb_node_get(n, "type")) return fail(err, n, "condition: missing required key 'type' (enter, distance, time_to_arrival, speed, standstill, after, input, time)", 0, 0);
    int t = -1;
    for (int i = 0; i < 8; i++) if (!strcmp(f.type, COND_NAMES[i])) t = i;
    if (t < 0) return fail(err, at_key(n, "type"), "condition type '%s': expected enter, distance, time_to_arrival, speed, standstill, after, input or time", f.type, 0);
    c->type = (sc_cond_type_t)t;
    for (int i = 0; i < pb_node_count(n); i++) {
        const char *k = pb_node_key(n, i);
        if (!strcmp(k, "type") || !strcmp(k, "edge") || !strcmp(k, "delay_s")) continue;
        char key[40], al[80];
        snprintf(key, sizeof key, " %s ", k);
        snprintf(al, sizeof al, " %s ", COND_KEYS[t]);
        if (!strstr(al, key)) return fail(err, pb_node_at(n, i), "key '%s' does not apply to a '%s' condition", k, f.type);
    }
    if (!strcmp(f.edge, "none")) c->edge = SC_EDGE_NONE;
    else if (!strcmp(f.edge, "rising")) c->edge = SC_EDGE_RISING;
    else if (!strcmp(f.edge, "falling")) c->edge = SC_EDGE_FALLING;
    else if (!strcmp(f.edge, "rising_or_falling")) c->edge = SC_EDGE_BOTH;
    else return fail(err, at_key(n, "edge"), "edge '%s': expected none, rising, falling or rising_or_falling", f.edge, 0);
    if (!(f.delay_s >= 0 && f.delay_s <= 3600)) return fail(err, at_key(n, "delay_s"), "delay_s: expected 0 to 3600 s", 0, 0);
    c->delay_s = f.delay_s;
    c->has_below = pb_node_get(n, "below") != NULL;
    c->has_above = pb_node_get(n, "above") != NULL;
    c->below = f.below; c->above = f.above;
    if (!isfinite(f.below) || !isfinite(f.above)) return fail(err, n, "condition: thresholds must be finite", 0, 0);
    switch (c->type) {
    case SC_COND_ENTER:
        if (!f.volume[0]) return fail(err, n, "enter condition: missing required key 'volume'", 0, 0);
        c->volume = sc_find_volume(sc, f.volume);
        if (c->volume < 0) return unknown_id(err, at_key(n, "volume"), "volume", f.volume);
        break;
    case SC_COND_DISTANCE:
    case SC_COND_TTA:
        if (!!pb_node_get(n, "point") == !!f.stop_line[0])
            return fail(err, n, "%s condition: give exactly one of point or stop_line", f.type, 0);
        if (f.stop_line[0]) {
            c->stop_line = find_stop(sc, f.stop_line);
            if (c->stop_line < 0) return unknown_id(err, at_key(n, "stop_line"), "stop line (not in the site's route)", f.stop_line);
        } else {
            if (!finite_all(f.point, 2)) return fail(err, at_key(n, "point"), "point is not finite", 0, 0);
            memcpy(c->point, f.point, sizeof c->point);
        }
        if (c->type == SC_COND_TTA ? !c->has_below : c->has_below == c->has_above)
            return fail(err, n, c->type == SC_COND_TTA ? "time_to_arrival condition: needs below (s)" : "distance condition: give exactly one of below or above (m)", 0, 0);
        break;
    case SC_COND_SPEED:
        if (c->has_below == c->has_above) return fail(err, n, "speed condition: give exactly one of below or above (m/s)", 0, 0);
        break;
    case SC_COND_STANDSTILL:
        if (!(f.duration_s >= 0 && f.duration_s <= 3600) || !pb_node_get(n, "duration_s"))
            return fail(err, at_key(n, "duration_s"), "standstill condition: needs duration_s in 0 to 3600 s", 0, 0);
        c->duration_s = f.duration_s;
        break;
    case SC_COND_AFTER:
        if (!f.trigger[0]) return fail(err, n, "after condition: missing required key 'trigger'", 0, 0);
        c->after_trigger = sc_find_trigger(sc, f.trigger);
        if (c->after_trigger < 0) return unknown_id(err, at_key(n, "trigger"), "trigger", f.trigger);
        if (!(f.elapsed_s >= 0 && f.elapsed_s <= 3600)) return fail(err, at_key(n, "elapsed_s"), "elapsed_s: expected 0 to 3600 s", 0, 0);
        c->after_s = f.elapsed_s;
        break;
    case SC_COND_INPUT:
        if (!f.input[0]) return fail(err, n, "input condition: missing required key 'input' (e.g. proceed)", 0, 0);
        strcpy(c->input, f.input);
        break;
    case SC_COND_TIME:
        if (!c->has_above) return fail(err, n, "time condition: needs above (s since the first pose)", 0, 0);
        break;
    }
    return 0;
}

/* when: a condition, {all: [conditions]} or {any: [condition | {all: [...]}]}. */
static int count_conds(const pb_cfg_node_t *when, int *ngroups, pb_err_t *err)
{
    if (!when || pb_node_kind(when) != PB_NODE_MAP) return fail(err, when, "when: expected a condition, {all: [...]} or {any: [...]}", 0, 0);
    const pb_cfg_node_t *all = pb_node_get(when, "all"), *any = pb_node_get(when, "any");
    if ((all || any) && pb_node_count(when) != 1) return fail(err, when, "when: 'all' or 'any' must be the only key", 0, 0);
    if (all) {
        if (pb_node_kind(all) != PB_NODE_LIST || pb_node_count(all) < 1) return fail(err, all, "all: a list of at least one condition", 0, 0);
        *ngroups = 1;
        return pb_node_count(all);
    }
    if (any) {
        if (pb_node_kind(any) != PB_NODE_LIST || pb_node_count(any) < 1 || pb_node_count(any) > 64)
            return fail(err, any, "any: a list of 1 to 64 conditions or {all: [...]}", 0, 0);
        int total = 0;
        *ngroups = pb_node_count(any);
        for (int i = 0; i < pb_node_count(any); i++) {
            const pb_cfg_node_t *g = pb_node_at(any, i);
            if (pb_node_kind(g) != PB_NODE_MAP) return fail(err, g, "any: each item is a condition or {all: [...]}", 0, 0);
            const pb_cfg_node_t *ga = pb_node_get(g, "all");
            if (pb_node_get(g, "any")) return fail(err, g, "any: groups do not nest deeper than any -> all -> condition", 0, 0);
            if (ga) {
                if (pb_node_count(g) != 1) return fail(err, g, "'all' must be the only key", 0, 0);
                if (pb_node_kind(ga) != PB_NODE_LIST || pb_node_count(ga) < 1) return fail(err, ga, "all: a list of at least one condition", 0, 0);
                total += pb_node_count(ga);
            } else total += 1;
        }
        return total;
    }
    *ngroups = 1;
    return 1;
}

static int read_trigger_conds(const pb_cfg_node_t *when, sc_scenario_t *sc, sc_trigger_t *t, pb_err_t *err)
{
    int ng = 0;
    int nc = count_conds(when, &ng, err);
    if (nc < 0) return -1;
    t->conds = calloc(nc, sizeof *t->conds);
    t->ngroups = ng;
    const pb_cfg_node_t *all = pb_node_get(when, "all"), *any = pb_node_get(when, "any");
    int k = 0;
    if (all) {
        for (int i = 0; i < pb_node_count(all); i++, t->nconds++)
            if (read_cond(pb_node_at(all, i), sc, 0, &t->conds[k++], err)) return -1;
    } else if (any) {
        for (int gi = 0; gi < pb_node_count(any); gi++) {
            const pb_cfg_node_t *g = pb_node_at(any, gi), *ga = pb_node_get(g, "all");
            if (ga) {
                for (int i = 0; i < pb_node_count(ga); i++, t->nconds++)
                    if (read_cond(pb_node_at(ga, i), sc, gi, &t->conds[k++], err)) return -1;
            } else {
                t->nconds++;
                if (read_cond(g, sc, gi, &t->conds[k++], err)) return -1;
            }
        }
    } else {
        t->nconds = 1;
        if (read_cond(when, sc, 0, &t->conds[0], err)) return -1;
    }
    return 0;
}

static const char *const ACT_NAMES[] = { "start", "stop", "animate", "place", "emit" };
static const char *const ACT_KEYS[] = { "behaviour", "behaviour", "agent animation", "agent xy yaw_deg", "event" };

static int read_action(const pb_cfg_node_t *n, sc_scenario_t *sc, sc_action_t *a, pb_err_t *err)
{
    struct { char type[16], behaviour[SC_ID_LEN], agent[SC_ID_LEN], animation[SC_ID_LEN], event[SC_ID_LEN]; double xy[2], yaw_deg; } f;
    memset(&f, 0, sizeof f);
#define F(k, t, m, l) { k, t, offsetof(typeof(f), m), l, 0 }
    const pb_cfg_field_t fields[] = {
        F("type", PB_CFG_STRING, type, 16), F("behaviour", PB_CFG_STRING, behaviour, SC_ID_LEN),
        F("agent", PB_CFG_STRING, agent, SC_ID_LEN), F("animation", PB_CFG_STRING, animation, SC_ID_LEN),
        F("event", PB_CFG_STRING, event, SC_ID_LEN), F("xy", PB_CFG_DOUBLES, xy, 2), F("yaw_deg", PB_CFG_DOUBLE, yaw_deg, 0), PB_CFG_END };
#undef F
    if (pb_cfg_read(n, fields, &f, err)) return -1;
    memset(a, 0, sizeof *a);
    a->line = pb_node_line(n);
    a->behaviour = -1; a->agent = -1;
    int t = -1;
    for (int i = 0; i < 5; i++) if (!strcmp(f.type, ACT_NAMES[i])) t = i;
    if (t < 0) return fail(err, at_key(n, "type"), "action type '%s': expected start, stop, animate, place or emit", f.type, 0);
    a->type = (sc_act_type_t)t;
    for (int i = 0; i < pb_node_count(n); i++) {
        const char *k = pb_node_key(n, i);
        if (!strcmp(k, "type")) continue;
        char key[40], al[80];
        snprintf(key, sizeof key, " %s ", k);
        snprintf(al, sizeof al, " %s ", ACT_KEYS[t]);
        if (!strstr(al, key)) return fail(err, pb_node_at(n, i), "key '%s' does not apply to a '%s' action", k, f.type);
    }
    switch (a->type) {
    case SC_ACT_START:
    case SC_ACT_STOP:
        a->behaviour = sc_find_behaviour(sc, f.behaviour);
        if (a->behaviour < 0) return unknown_id(err, at_key(n, "behaviour"), "behaviour", f.behaviour);
        break;
    case SC_ACT_ANIMATE:
    case SC_ACT_PLACE:
        a->agent = sc_find_agent(sc, f.agent);
        if (a->agent < 0) return unknown_id(err, at_key(n, "agent"), "agent", f.agent);
        if (a->type == SC_ACT_ANIMATE) {
            if (!f.animation[0]) return fail(err, n, "animate action: missing required key 'animation'", 0, 0);
            if (check_name(n, "animation", f.animation, err)) return -1;
            strcpy(a->name, f.animation);
        } else {
            if (!pb_node_get(n, "xy") || !finite_all(f.xy, 2) || !isfinite(f.yaw_deg)) return fail(err, n, "place action: needs a finite xy", 0, 0);
            memcpy(a->xy, f.xy, sizeof a->xy);
            a->yaw = f.yaw_deg * DEG;
        }
        break;
    case SC_ACT_EMIT:
        if (!f.event[0]) return fail(err, n, "emit action: missing required key 'event'", 0, 0);
        if (check_name(n, "event", f.event, err)) return -1;
        strcpy(a->name, f.event);
        break;
    }
    return 0;
}

/* ---------------------------------------------------------------- the file */
int sc_find_volume(const sc_scenario_t *sc, const char *id)
{ for (int i = 0; i < sc->nvolumes; i++) if (!strcmp(sc->volumes[i].id, id)) return i; return -1; }
int sc_find_agent(const sc_scenario_t *sc, const char *id)
{ for (int i = 0; i < sc->nagents; i++) if (!strcmp(sc->agents[i].id, id)) return i; return -1; }
int sc_find_behaviour(const sc_scenario_t *sc, const char *id)
{ for (int i = 0; i < sc->nbehaviours; i++) if (!strcmp(sc->behaviours[i].id, id)) return i; return -1; }
int sc_find_trigger(const sc_scenario_t *sc, const char *id)
{ for (int i = 0; i < sc->ntriggers; i++) if (!strcmp(sc->triggers[i].id, id)) return i; return -1; }

double sc_path_length(const sc_behaviour_t *b, const double p0[2], int upto)
{
    double L = 0, x = p0[0], y = p0[1];
    for (int i = 0; i <= upto && i < b->npts; i++) {
        L += hypot(b->pts[i].xy[0] - x, b->pts[i].xy[1] - y);
        x = b->pts[i].xy[0]; y = b->pts[i].xy[1];
    }
    return L;
}

void sc_free(sc_scenario_t *sc)
{
    for (int i = 0; i < sc->nbehaviours; i++) free(sc->behaviours[i].pts);
    for (int i = 0; i < sc->ntriggers; i++) { free(sc->triggers[i].conds); free(sc->triggers[i].actions); }
    free(sc->volumes); free(sc->agents); free(sc->behaviours); free(sc->triggers); free(sc->stops);
    memset(sc, 0, sizeof *sc);
}

/* Duplicate ids within one kind are refused (ids name things in events and logs). */
#define CHECK_DUP(arr, count, what, nodes)                                                                  \
    for (int i = 0; i < (count); i++)                                                                      \
        for (int j = 0; j < i; j++)                                                                        \
            if (!strcmp((arr)[i].id, (arr)[j].id)) {                                                       \
                pb_err_set(err, "%s:%d: duplicate %s id '%s' (first at line %d)", path, (arr)[i].line, what, \
                           (arr)[i].id, (arr)[j].line);                                                    \
                goto out;                                                                                  \
            }

int sc_load(const char *path, const pb_route_t *route, sc_scenario_t *sc, pb_err_t *err)
{
    memset(sc, 0, sizeof *sc);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    int rc = -1;
    snprintf(sc->path, sizeof sc->path, "%s", path);
    sc->render_distance_m = 45.0;
    sc->jump_m = 3.0;
    sc->stop_gap_m = 0.5;
    struct { char scenario[SC_ID_LEN], description[256], on_jump[16]; double render, jump_m, stop_gap;
             const pb_cfg_node_t *volumes, *agents, *behaviours, *triggers; } top;
    memset(&top, 0, sizeof top);
    strcpy(top.on_jump, "skip");
    top.render = 45.0; top.jump_m = 3.0; top.stop_gap = 0.5;
#define T(k, t, m, l, r) { k, t, offsetof(typeof(top), m), l, r }
    const pb_cfg_field_t tf[] = {
        T("scenario", PB_CFG_STRING, scenario, SC_ID_LEN, 1), T("description", PB_CFG_STRING, description, 256, 0),
        T("render_distance_m", PB_CFG_DOUBLE, render, 0, 0), T("pose_jump_m", PB_CFG_DOUBLE, jump_m, 0, 0),
        T("on_pose_jump", PB_CFG_STRING, on_jump, 16, 0), T("stop_gap_m", PB_CFG_DOUBLE, stop_gap, 0, 0),
        T("volumes", PB_CFG_NODE, volumes, 0, 0), T("agents", PB_CFG_NODE, agents, 0, 0),
        T("behaviours", PB_CFG_NODE, behaviours, 0, 0), T("triggers", PB_CFG_NODE, triggers, 0, 1), PB_CFG_END };
#undef T
    const pb_cfg_node_t *root = pb_cfg_root(cfg);
    if (pb_cfg_read(root, tf, &top, err)) goto out;
    if (check_id(root, top.scenario, err)) { pb_err_set(err, "%s:%d: scenario: an id of letters, digits, '_', '-', '.'", path, pb_node_line(at_key(root, "scenario"))); goto out; }
    strcpy(sc->id, top.scenario);
    strcpy(sc->description, top.description);
    if (!(top.render > 0 && top.render <= 10000)) { fail(err, at_key(root, "render_distance_m"), "render_distance_m: expected 0 to 10000 m", 0, 0); goto out; }
    if (!(top.jump_m >= 0.5 && top.jump_m <= 1000)) { fail(err, at_key(root, "pose_jump_m"), "pose_jump_m: expected 0.5 to 1000 m", 0, 0); goto out; }
    if (!(top.stop_gap >= 0 && top.stop_gap <= 20)) { fail(err, at_key(root, "stop_gap_m"), "stop_gap_m: expected 0 to 20 m", 0, 0); goto out; }
    if (!strcmp(top.on_jump, "skip")) sc->on_jump = SC_JUMP_SKIP;
    else if (!strcmp(top.on_jump, "fire")) sc->on_jump = SC_JUMP_FIRE;
    else { fail(err, at_key(root, "on_pose_jump"), "on_pose_jump '%s': expected skip or fire", top.on_jump, 0); goto out; }
    sc->render_distance_m = top.render;
    sc->jump_m = top.jump_m;
    sc->stop_gap_m = top.stop_gap;

    if (route) {
        sc->nstops = route->nstops;
        sc->stops = calloc(route->nstops ? route->nstops : 1, sizeof *sc->stops);
        for (int i = 0; i < route->nstops; i++) {
            snprintf(sc->stops[i].id, sizeof sc->stops[i].id, "%s", route->stops[i].id);
            snprintf(sc->stops[i].crosswalk, sizeof sc->stops[i].crosswalk, "%s", route->stops[i].crosswalk);
            memcpy(sc->stops[i].xy, route->stops[i].xy, sizeof sc->stops[i].xy);
            sc->stops[i].s = route->stops[i].s;
        }
    }
    if (list_of(top.volumes, "volumes", err) || list_of(top.agents, "agents", err) ||
        list_of(top.behaviours, "behaviours", err) || list_of(top.triggers, "triggers", err)) goto out;

    int nv = pb_node_count(top.volumes);
    sc->volumes = calloc(nv ? nv : 1, sizeof *sc->volumes);
    for (int i = 0; i < nv; i++, sc->nvolumes++)
        if (read_volume(pb_node_at(top.volumes, i), &sc->volumes[i], err)) goto out;
    CHECK_DUP(sc->volumes, sc->nvolumes, "volume", 0);

    int na = pb_node_count(top.agents);
    sc->agents = calloc(na ? na : 1, sizeof *sc->agents);
    for (int i = 0; i < na; i++, sc->nagents++)
        if (read_agent(pb_node_at(top.agents, i), &sc->agents[i], err)) goto out;
    CHECK_DUP(sc->agents, sc->nagents, "agent", 0);

    int nb = pb_node_count(top.behaviours);
    sc->behaviours = calloc(nb ? nb : 1, sizeof *sc->behaviours);
    for (int i = 0; i < nb; i++) {
        sc->nbehaviours++;   /* counted first so sc_free frees a half-read path */
        if (read_behaviour(pb_node_at(top.behaviours, i), sc, &sc->behaviours[i], err)) goto out;
    }
    CHECK_DUP(sc->behaviours, sc->nbehaviours, "behaviour", 0);

    /* Triggers: ids first, so 'after' conditions may name a later trigger. */
    int nt = pb_node_count(top.triggers);
    if (nt < 1) { fail(err, top.triggers ? top.triggers : root, "triggers: a list of at least one trigger", 0, 0); goto out; }
    sc->triggers = calloc(nt, sizeof *sc->triggers);
    for (int i = 0; i < nt; i++) {
        const pb_cfg_node_t *tn = pb_node_at(top.triggers, i);
        const pb_cfg_node_t *idn = pb_node_kind(tn) == PB_NODE_MAP ? pb_node_get(tn, "id") : NULL;
        if (!idn || !pb_node_str(idn) || strlen(pb_node_str(idn)) >= SC_ID_LEN) {
            fail(err, idn ? idn : tn, "trigger: needs an id (a string of at most 47 characters)", 0, 0);
            goto out;
        }
        strcpy(sc->triggers[i].id, pb_node_str(idn));
        sc->triggers[i].line = pb_node_line(tn);
    }
    sc->ntriggers = nt;
    CHECK_DUP(sc->triggers, sc->ntriggers, "trigger", 0);
    for (int i = 0; i < nt; i++) {
        const pb_cfg_node_t *tn = pb_node_at(top.triggers, i);
        sc_trigger_t *t = &sc->triggers[i];
        struct { char id[SC_ID_LEN]; const pb_cfg_node_t *when, *actions; } f;
        memset(&f, 0, sizeof f);
        const pb_cfg_field_t fields[] = {
            { "id", PB_CFG_STRING, offsetof(typeof(f), id), SC_ID_LEN, 1 },
            { "when", PB_CFG_NODE, offsetof(typeof(f), when), 0, 1 },
            { "actions", PB_CFG_NODE, offsetof(typeof(f), actions), 0, 1 }, PB_CFG_END };
        if (pb_cfg_read(tn, fields, &f, err) || check_id(tn, f.id, err)) goto out;
        if (read_trigger_conds(f.when, sc, t, err)) goto out;
        if (pb_node_kind(f.actions) != PB_NODE_LIST || pb_node_count(f.actions) < 1) {
            fail(err, f.actions, "trigger '%s': actions: a list of at least one action", f.id, 0);
            goto out;
        }
        int nact = pb_node_count(f.actions);
        t->actions = calloc(nact, sizeof *t->actions);
        for (int k = 0; k < nact; k++, t->nactions++)
            if (read_action(pb_node_at(f.actions, k), sc, &t->actions[k], err)) goto out;
    }
    /* A behaviour is started by at most one agent at a time: two behaviours of one
     * agent may run one after the other (start replaces the running one). */
    rc = 0;
out:
    if (rc) sc_free(sc);
    pb_cfg_free(cfg);
    return rc;
}
