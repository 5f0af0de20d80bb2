/* World: reading world.yaml, the ray-casting grid and the primitive intersections. */
#include "world.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "actors.h"
#include "pb_config.h"
#include "rng.h"

#define EPS 1e-6

static int find_class(const world_t *w, const char *name, const pb_cfg_node_t *where, uint8_t *out, pb_err_t *err)
{
    for (int i = 0; i < w->nclasses; i++)
        if (!strcmp(w->class_name[i], name)) { *out = (uint8_t)i; return 0; }
    return pb_err_set(err, "%s:%d: unknown class '%s' (not under classes:)", pb_node_file(where), pb_node_line(where), name);
}

static int read_object(world_t *w, const pb_cfg_node_t *node, prim_t *p, pb_err_t *err)
{
    struct {
        char type[16], cls[24], day[8], group[24];
        const pb_cfg_node_t *center;
        double yaw_deg, size[3], z0, radius, height;
    } o = { "", "", "both", "", NULL, 0, { -1, -1, -1 }, 0, -1, -1 };
#define O(key, type, field, len, req) { key, type, offsetof(typeof(o), field), len, req }
    const pb_cfg_field_t f[] = {
        O("type", PB_CFG_STRING, type, sizeof o.type, 1), O("class", PB_CFG_STRING, cls, sizeof o.cls, 1),
        O("center", PB_CFG_NODE, center, 0, 1), O("yaw_deg", PB_CFG_DOUBLE, yaw_deg, 0, 0),
        O("size", PB_CFG_DOUBLES, size, 3, 0), O("z0", PB_CFG_DOUBLE, z0, 0, 0),
        O("radius", PB_CFG_DOUBLE, radius, 0, 0), O("height", PB_CFG_DOUBLE, height, 0, 0),
        O("day", PB_CFG_STRING, day, sizeof o.day, 0), O("group", PB_CFG_STRING, group, sizeof o.group, 0),
        PB_CFG_END };
#undef O
    if (pb_cfg_read(node, f, &o, err)) return -1;
    const char *file = pb_node_file(node);
    int line = pb_node_line(node);
    memset(p, 0, sizeof *p);
    if (find_class(w, o.cls, node, &p->cls, err)) return -1;
    if (!strcmp(o.day, "both")) p->day = DAY_BOTH;
    else if (!strcmp(o.day, "map")) p->day = DAY_MAP;
    else if (!strcmp(o.day, "drive")) p->day = DAY_DRIVE;
    else return pb_err_set(err, "%s:%d: day: expected both, map or drive, got '%s'", file, line, o.day);
    if (o.group[0]) {
        int g = 0;
        while (g < w->ngroups && strcmp(w->group_name[g], o.group)) g++;
        if (g == w->ngroups) {
            if (g == WORLD_MAX_GROUPS) return pb_err_set(err, "%s:%d: group: at most %d groups", file, line, WORLD_MAX_GROUPS);
            snprintf(w->group_name[w->ngroups++], sizeof w->group_name[0], "%s", o.group);
        }
        p->group = (uint8_t)(g + 1);
    }
    double c[3] = { 0, 0, 0 };
    if (!strcmp(o.type, "box")) {
        if (pb_node_doubles(o.center, "center", c, 2, err)) return -1;
        if (o.size[0] <= 0 || o.size[1] <= 0 || o.size[2] <= 0)
            return pb_err_set(err, "%s:%d: box: size [length, width, height] > 0 is required", file, line);
        p->kind = PRIM_BOX;
        p->c = cos(o.yaw_deg * M_PI / 180); p->s = sin(o.yaw_deg * M_PI / 180);
        p->hx = o.size[0] / 2; p->hy = o.size[1] / 2;
        p->z0 = o.z0; p->z1 = o.z0 + o.size[2];
        p->r = hypot(p->hx, p->hy);
    } else if (!strcmp(o.type, "cylinder")) {
        if (pb_node_doubles(o.center, "center", c, 2, err)) return -1;
        if (o.radius <= 0 || o.height <= 0)
            return pb_err_set(err, "%s:%d: cylinder: radius > 0 and height > 0 are required", file, line);
        p->kind = PRIM_CYLINDER;
        p->r = o.radius; p->z0 = o.z0; p->z1 = o.z0 + o.height;
    } else if (!strcmp(o.type, "sphere")) {
        if (pb_node_doubles(o.center, "center", c, 3, err)) return -1;
        if (o.radius <= 0) return pb_err_set(err, "%s:%d: sphere: radius > 0 is required", file, line);
        p->kind = PRIM_SPHERE;
        p->r = o.radius; p->z0 = c[2] - o.radius; p->z1 = c[2] + o.radius;
    } else {
        return pb_err_set(err, "%s:%d: type: expected box, cylinder or sphere, got '%s'", file, line, o.type);
    }
    p->cx = c[0]; p->cy = c[1]; p->cz = c[2];
    return 0;
}

/* Heights in world.yaml count from the ground: a box or cylinder reaches down to the
 * lowest ground under its footprint (a building on a slope has no gap beneath) and
 * up to its height above the ground at its centre; a sphere rises with the ground. */
static void stand_on_terrain(const terrain_t *T, prim_t *p)
{
    if (!T->enabled) return;
    double hc = terrain_height(T, p->cx, p->cy);
    if (p->kind == PRIM_SPHERE) { p->cz += hc; p->z0 += hc; p->z1 += hc; return; }
    double lo = hc;
    for (int k = 0; k < 4; k++) {
        double u = (k & 1) ? 1 : -1, v = (k & 2) ? 1 : -1, x, y;
        if (p->kind == PRIM_BOX) { x = p->cx + p->c * u * p->hx - p->s * v * p->hy; y = p->cy + p->s * u * p->hx + p->c * v * p->hy; }
        else { x = p->cx + u * p->r; y = p->cy + v * p->r; }
        lo = fmin(lo, terrain_height(T, x, y));
    }
    p->z0 += p->z0 == 0 ? lo : hc;
    p->z1 += hc;
}

static int read_traffic(world_t *w, const pb_cfg_node_t *node, traffic_t *t, pb_err_t *err)
{
    struct { char kind[16], cls[24]; double size[3], z0, speed, phase_s, lane_offset; } o =
        { "car", "", { 0, 0, 0 }, 0.2, 8.0, 0, 3.5 };
#define O(key, type, field, len, req) { key, type, offsetof(typeof(o), field), len, req }
    const pb_cfg_field_t f[] = {
        O("kind", PB_CFG_STRING, kind, sizeof o.kind, 0), O("class", PB_CFG_STRING, cls, sizeof o.cls, 1),
        O("size", PB_CFG_DOUBLES, size, 3, 1), O("z0", PB_CFG_DOUBLE, z0, 0, 0),
        O("speed", PB_CFG_DOUBLE, speed, 0, 1), O("phase_s", PB_CFG_DOUBLE, phase_s, 0, 0),
        O("lane_offset", PB_CFG_DOUBLE, lane_offset, 0, 0), PB_CFG_END };
#undef O
    if (pb_cfg_read(node, f, &o, err)) return -1;
    if (o.size[0] <= 0 || o.size[1] <= 0 || o.size[2] <= 0 || o.speed < 0)
        return pb_err_set(err, "%s:%d: traffic: size > 0 and speed >= 0 are required", pb_node_file(node), pb_node_line(node));
    memcpy(t->kind, o.kind, sizeof t->kind);
    if (find_class(w, o.cls, node, &t->cls, err)) return -1;
    memcpy(t->size, o.size, sizeof t->size);
    t->z0 = o.z0; t->speed = o.speed; t->phase_s = o.phase_s; t->lane_offset = o.lane_offset;
    return 0;
}

int world_load(const char *path, const pb_route_t *route, world_t *w, pb_err_t *err)
{
    memset(w, 0, sizeof *w);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    int rc = -1;
    struct { const pb_cfg_node_t *classes, *traffic, *objects, *terrain, *lead, *crossers; char ground[24], paint[24]; } top =
        { 0, 0, 0, 0, 0, 0, "", "" };
    const pb_cfg_field_t f[] = {
        { "classes", PB_CFG_NODE, offsetof(typeof(top), classes), 0, 1 },
        { "ground_class", PB_CFG_STRING, offsetof(typeof(top), ground), sizeof top.ground, 1 },
        { "paint_class", PB_CFG_STRING, offsetof(typeof(top), paint), sizeof top.paint, 0 },
        { "traffic", PB_CFG_NODE, offsetof(typeof(top), traffic), 0, 0 },
        { "objects", PB_CFG_NODE, offsetof(typeof(top), objects), 0, 1 },
        { "terrain", PB_CFG_NODE, offsetof(typeof(top), terrain), 0, 0 },
        { "lead_car", PB_CFG_NODE, offsetof(typeof(top), lead), 0, 0 },
        { "crossers", PB_CFG_NODE, offsetof(typeof(top), crossers), 0, 0 }, PB_CFG_END };
    const pb_cfg_node_t *root = pb_cfg_root(cfg);
    if (pb_cfg_read(root, f, &top, err)) goto out;
    if (pb_node_kind(top.classes) != PB_NODE_MAP) {
        pb_err_set(err, "%s:%d: classes: expected a mapping of class: albedo", path, pb_node_line(top.classes));
        goto out;
    }
    w->nclasses = pb_node_count(top.classes);
    if (w->nclasses > WORLD_MAX_CLASSES) {
        pb_err_set(err, "%s:%d: classes: at most %d", path, pb_node_line(top.classes), WORLD_MAX_CLASSES);
        goto out;
    }
    for (int i = 0; i < w->nclasses; i++) {
        snprintf(w->class_name[i], sizeof w->class_name[i], "%s", pb_node_key(top.classes, i));
        if (pb_node_double(pb_node_at(top.classes, i), w->class_name[i], &w->albedo[i], err)) goto out;
        if (w->albedo[i] < 0 || w->albedo[i] > 1) {
            const pb_cfg_node_t *n = pb_node_at(top.classes, i);
            pb_err_set(err, "%s:%d: %s: albedo must be in 0..1", path, pb_node_line(n), w->class_name[i]);
            goto out;
        }
    }
    if (find_class(w, top.ground, root, &w->ground_cls, err)) goto out;
    w->foliage_cls = -1;
    for (int i = 0; i < w->nclasses; i++)
        if (!strcmp(w->class_name[i], "foliage")) w->foliage_cls = i;
    w->paint_cls = w->ground_cls;
    if (top.paint[0] && find_class(w, top.paint, root, &w->paint_cls, err)) goto out;
    if (top.traffic) {
        w->ntraffic = pb_node_count(top.traffic);
        if (w->ntraffic > WORLD_MAX_TRAFFIC) {
            pb_err_set(err, "%s:%d: traffic: at most %d", path, pb_node_line(top.traffic), WORLD_MAX_TRAFFIC);
            goto out;
        }
        for (int i = 0; i < w->ntraffic; i++)
            if (read_traffic(w, pb_node_at(top.traffic, i), &w->traffic[i], err)) goto out;
    }
    if (terrain_load(&w->terrain, top.terrain, route, WORLD_TERRAIN_MARGIN_M, err)) goto out;
    w->actors = calloc(1, sizeof *w->actors);
    if (actors_load(w->actors, w, top.lead, top.crossers, err)) goto out;
    w->nprims = pb_node_count(top.objects);
    w->prims = calloc(w->nprims ? w->nprims : 1, sizeof *w->prims);
    for (int i = 0; i < w->nprims; i++) {
        if (read_object(w, pb_node_at(top.objects, i), &w->prims[i], err)) goto out;
        stand_on_terrain(&w->terrain, &w->prims[i]);
    }
    /* Crosswalk paint from the route: centre, unit axes along / across the road, half sizes. */
    w->ncw = route->ncw;
    w->cw = calloc(w->ncw ? w->ncw : 1, sizeof *w->cw);
    for (int i = 0; i < w->ncw; i++) {
        const pb_crosswalk_t *c = &route->cw[i];
        double y = c->yaw_deg * M_PI / 180;
        w->cw[i][0] = c->center[0]; w->cw[i][1] = c->center[1];
        w->cw[i][2] = cos(y); w->cw[i][3] = sin(y);
        w->cw[i][4] = c->width / 2; w->cw[i][5] = c->length / 2;
    }
    rc = 0;
out:
    if (rc) world_free(w);
    pb_cfg_free(cfg);
    return rc;
}

int world_group_off(world_t *w, const char *name, pb_err_t *err)
{
    for (int g = 0; g < w->ngroups; g++)
        if (!strcmp(w->group_name[g], name)) { w->groups_off |= 1u << g; return 0; }
    char known[WORLD_MAX_GROUPS * 26] = "";
    for (int g = 0; g < w->ngroups; g++) {
        strcat(known, g ? ", " : "");
        strcat(known, w->group_name[g]);
    }
    return pb_err_set(err, "--without: no object group '%s' in the world (groups: %s)", name, w->ngroups ? known : "none");
}

void world_free(world_t *w)
{
    if (w->actors) actors_free(w->actors);
    free(w->actors);
    terrain_free(&w->terrain);
    free(w->prims); free(w->cw); free(w->cell_start); free(w->cell_items); free(w->cell_maxz);
    memset(w, 0, sizeof *w);
}

static void prim_bounds(const prim_t *p, double b[4])
{
    double ex = p->r, ey = p->r;
    if (p->kind == PRIM_BOX) {
        ex = fabs(p->c) * p->hx + fabs(p->s) * p->hy;
        ey = fabs(p->s) * p->hx + fabs(p->c) * p->hy;
    }
    b[0] = p->cx - ex; b[1] = p->cy - ey; b[2] = p->cx + ex; b[3] = p->cy + ey;
}

void world_build_grid(world_t *w, int day, double cell)
{
    free(w->cell_start); free(w->cell_items); free(w->cell_maxz);
    double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
    w->max_z = 0;
    for (int i = 0; i < w->nprims; i++) {
        double b[4];
        prim_bounds(&w->prims[i], b);
        lo[0] = fmin(lo[0], b[0]); lo[1] = fmin(lo[1], b[1]);
        hi[0] = fmax(hi[0], b[2]); hi[1] = fmax(hi[1], b[3]);
        w->max_z = fmax(w->max_z, w->prims[i].z1);
    }
    if (w->nprims == 0) { lo[0] = lo[1] = 0; hi[0] = hi[1] = 1; }
    w->cell = cell;
    w->gx0 = lo[0] - cell; w->gy0 = lo[1] - cell;
    w->gnx = (int)ceil((hi[0] - w->gx0) / cell) + 1;
    w->gny = (int)ceil((hi[1] - w->gy0) / cell) + 1;
    int nc = w->gnx * w->gny;
    w->cell_start = calloc(nc + 1, sizeof *w->cell_start);
    w->cell_maxz = calloc(nc, sizeof *w->cell_maxz);
    for (int i = 0; i < nc; i++) w->cell_maxz[i] = -1e9f;
    for (int pass = 0; pass < 2; pass++) {  /* count, then fill */
        int32_t *fill = pass ? calloc(nc, sizeof *fill) : NULL;
        for (int i = 0; i < w->nprims; i++) {
            const prim_t *p = &w->prims[i];
            if (p->day != DAY_BOTH && p->day != day) continue;
            if (p->group && (w->groups_off >> (p->group - 1) & 1)) continue;
            double b[4];
            prim_bounds(p, b);
            int x0 = (int)((b[0] - w->gx0) / cell), x1 = (int)((b[2] - w->gx0) / cell);
            int y0 = (int)((b[1] - w->gy0) / cell), y1 = (int)((b[3] - w->gy0) / cell);
            for (int y = y0; y <= y1; y++)
                for (int x = x0; x <= x1; x++) {
                    int c = y * w->gnx + x;
                    if (!pass) { w->cell_start[c + 1]++; if (p->z1 > w->cell_maxz[c]) w->cell_maxz[c] = (float)p->z1; }
                    else w->cell_items[w->cell_start[c] + fill[c]++] = i;
                }
        }
        if (!pass) {
            for (int c = 0; c < nc; c++) w->cell_start[c + 1] += w->cell_start[c];
            w->cell_items = malloc((w->cell_start[nc] + 1) * sizeof *w->cell_items);
        }
        free(fill);
    }
}

int world_vehicle(const world_t *w, double cx, double cy, double c, double s, const double size[3], double z0,
                  uint8_t cls, int bury, mover_t *out)
{
    const terrain_t *T = &w->terrain;
    const double hx = size[0] / 2, hy = size[1] / 2, down = bury ? 1000 : 0;
    mover_t *b = &out[0];
    b->cx = cx; b->cy = cy; b->c = c; b->s = s; b->hx = hx; b->hy = hy; b->cls = cls;
    /* the road's slope under it, end to end and side to side */
    b->gx = (terrain_height(T, cx + c * hx, cy + s * hx) - terrain_height(T, cx - c * hx, cy - s * hx)) / (2 * hx);
    b->gy = (terrain_height(T, cx - s * hy, cy + c * hy) - terrain_height(T, cx + s * hy, cy - c * hy)) / (2 * hy);
    b->z0 = terrain_height(T, cx, cy) + z0 - down;
    b->z1 = b->z0 + size[2];
    /* wheels: a car's 0.66 m, a bus's or a truck's (longer than 6 m) 1.0 m, 0.25 m wide, the
     * axles a fifth of the length in from the ends, just inside the body's sides */
    const double dia = size[0] > 6 ? 1.0 : 0.66, width = 0.25, inset = 0.2 * size[0];
    for (int k = 0; k < 4; k++) {
        const double u = (k & 1 ? 1 : -1) * (hx - inset), v = (k & 2 ? 1 : -1) * (hy - width / 2 - 0.02);
        mover_t *m = &out[1 + k];
        *m = *b;
        m->cx = cx + c * u - s * v; m->cy = cy + s * u + c * v;
        m->hx = dia / 2; m->hy = width / 2;
        m->z0 = terrain_height(T, m->cx, m->cy) - down;
        m->z1 = m->z0 + dia;
    }
    return 5;
}

int world_movers(const world_t *w, const pb_route_t *route, double t, uint64_t seed, mover_t *out)
{
    int n = 0;
    for (int i = 0; i < w->ntraffic; i++) {
        const traffic_t *tr = &w->traffic[i];
        /* seed shifts each vehicle by up to +-50 m; they drive against the route direction */
        double shift = (rng_uniform(seed, RNG_TRAFFIC, (uint64_t)i, 0) - 0.5) * 100.0;
        pb_route_point_t rp;
        pb_route_eval(route, tr->phase_s + shift - tr->speed * t, &rp);
        double c = cos(rp.yaw), s = sin(rp.yaw);
        n += world_vehicle(w, rp.x - s * tr->lane_offset, rp.y + c * tr->lane_offset, -c, -s, tr->size, tr->z0, tr->cls, 0,
                           out + n);
    }
    return n + (w->actors ? actors_movers(w->actors, w, t, out + n, WORLD_MAX_MOVERS - n) : 0);
}

/* ---------------------------------------------------------------- intersections */

/* A box turned by (c, s) whose heights rise by gx, gy per metre along its own x, y (0 for
 * the static world's boxes): the ray's height is taken relative to that slope. */
static inline double ray_box(double cx, double cy, double c, double s, double hx, double hy, double z0, double z1,
                             double gx, double gy, const double o[3], const double d[3])
{
    double px = (o[0] - cx) * c + (o[1] - cy) * s, py = -(o[0] - cx) * s + (o[1] - cy) * c;
    double dx = d[0] * c + d[1] * s, dy = -d[0] * s + d[1] * c;
    double tn = -INFINITY, tf = INFINITY;
    if (fabs(dx) > 1e-12) {
        double a = (-hx - px) / dx, b = (hx - px) / dx;
        if (a > b) { double t = a; a = b; b = t; }
        tn = a; tf = b;
    } else if (fabs(px) > hx) return INFINITY;
    if (fabs(dy) > 1e-12) {
        double a = (-hy - py) / dy, b = (hy - py) / dy;
        if (a > b) { double t = a; a = b; b = t; }
        if (a > tn) tn = a;
        if (b < tf) tf = b;
    } else if (fabs(py) > hy) return INFINITY;
    double oz = o[2] - gx * px - gy * py, dz = d[2] - gx * dx - gy * dy;
    if (fabs(dz) > 1e-12) {
        double a = (z0 - oz) / dz, b = (z1 - oz) / dz;
        if (a > b) { double t = a; a = b; b = t; }
        if (a > tn) tn = a;
        if (b < tf) tf = b;
    } else if (oz < z0 || oz > z1) return INFINITY;
    return (tn <= tf && tn > EPS) ? tn : INFINITY;
}

static inline double ray_cylinder(const prim_t *p, const double o[3], const double d[3])
{
    double ox = o[0] - p->cx, oy = o[1] - p->cy;
    double a = d[0] * d[0] + d[1] * d[1], b = ox * d[0] + oy * d[1], c = ox * ox + oy * oy - p->r * p->r;
    double best = INFINITY;
    double disc = b * b - a * c;
    if (disc >= 0 && a > 1e-12) {
        double t = (-b - sqrt(disc)) / a;
        double z = o[2] + t * d[2];
        if (t > EPS && z >= p->z0 && z <= p->z1) best = t;
    }
    if (fabs(d[2]) > 1e-12) {   /* caps */
        double zc = d[2] < 0 ? p->z1 : p->z0;
        double t = (zc - o[2]) / d[2];
        if (t > EPS && t < best) {
            double x = ox + t * d[0], y = oy + t * d[1];
            if (x * x + y * y <= p->r * p->r) best = t;
        }
    }
    return best;
}

/* Where the line o + t d enters and leaves the sphere; 0 when it misses. */
static inline int sphere_span(const prim_t *p, const double o[3], const double d[3], double *t_in, double *t_out)
{
    double ox = o[0] - p->cx, oy = o[1] - p->cy, oz = o[2] - p->cz;
    double b = ox * d[0] + oy * d[1] + oz * d[2], c = ox * ox + oy * oy + oz * oz - p->r * p->r;
    double disc = b * b - c;
    if (disc < 0) return 0;
    *t_in = -b - sqrt(disc);
    *t_out = -b + sqrt(disc);
    return 1;
}

static inline double ray_sphere(const prim_t *p, const double o[3], const double d[3])
{
    double t, t_out;
    if (!sphere_span(p, o, d, &t, &t_out)) return INFINITY;
    return t > EPS ? t : INFINITY;
}

/* A beam into a porous canopy: it stops at an exponential depth (mean depth_m) inside the
 * sphere, drawn from (key, id), or goes through it (INFINITY). */
static inline double ray_canopy(const prim_t *p, const double o[3], const double d[3], double depth_m, uint64_t key,
                                int id)
{
    double t_in, t_out;
    if (!sphere_span(p, o, d, &t_in, &t_out)) return INFINITY;
    t_in = fmax(t_in, EPS);
    if (t_out <= t_in) return INFINITY;
    double u = ((double)(rng_u64(key, RNG_FOLIAGE, (uint64_t)id, 0) >> 11) + 0.5) * (1.0 / 9007199254740992.0);
    double t = t_in - depth_m * log(u);
    return t < t_out ? t : INFINITY;
}

static inline double ray_prim(const prim_t *p, const double o[3], const double d[3])
{
    switch (p->kind) {
    case PRIM_BOX: return ray_box(p->cx, p->cy, p->c, p->s, p->hx, p->hy, p->z0, p->z1, 0, 0, o, d);
    case PRIM_CYLINDER: return ray_cylinder(p, o, d);
    default: return ray_sphere(p, o, d);
    }
}

static int ground_class_at(const world_t *w, double x, double y)
{
    for (int i = 0; i < w->ncw; i++) {
        const double *c = w->cw[i];
        double dx = x - c[0], dy = y - c[1];
        if (fabs(dx) > 10 || fabs(dy) > 10) continue;
        double along = dx * c[2] + dy * c[3], across = -dx * c[3] + dy * c[2];
        if (fabs(along) <= c[4] && fabs(across) <= c[5]) {
            /* zebra: 0.6 m bars running along the road, 0.6 m apart */
            double u = fmod(across + c[5], 1.2);
            return u < 0.6 ? w->paint_cls : w->ground_cls;
        }
    }
    return w->ground_cls;
}

int world_raycast(const world_t *w, const double o[3], const double d[3], double tmax,
                  const mover_t *movers, int nmovers, uint32_t *mail, uint32_t stamp, uint64_t ray_key, hit_t *hit)
{
    const int porous = ray_key != 0 && w->foliage_depth_m > 0 && w->foliage_cls >= 0;
    double best = tmax;
    int cls = -1, ground = 0;
    double tg = terrain_raycast(&w->terrain, o, d, best);
    if (tg < best) { best = tg; ground = 1; }
    for (int i = 0; i < nmovers; i++) {
        const mover_t *m = &movers[i];
        double t = ray_box(m->cx, m->cy, m->c, m->s, m->hx, m->hy, m->z0, m->z1, m->gx, m->gy, o, d);
        if (t < best) { best = t; cls = m->cls; ground = 0; }
    }
    /* 2-D DDA over the grid, from the origin (always inside the grid on this site;
     * clipped otherwise) until the nearest hit is closer than the cell's exit. */
    double dx = d[0], dy = d[1];
    double t0 = 0, t1 = best;
    double gx1 = w->gx0 + w->gnx * w->cell, gy1 = w->gy0 + w->gny * w->cell;
    if (fabs(dx) > 1e-12) {
        double a = (w->gx0 - o[0]) / dx, b = (gx1 - o[0]) / dx;
        if (a > b) { double t = a; a = b; b = t; }
        t0 = fmax(t0, a); t1 = fmin(t1, b);
    } else if (o[0] < w->gx0 || o[0] >= gx1) t1 = -1;
    if (fabs(dy) > 1e-12) {
        double a = (w->gy0 - o[1]) / dy, b = (gy1 - o[1]) / dy;
        if (a > b) { double t = a; a = b; b = t; }
        t0 = fmax(t0, a); t1 = fmin(t1, b);
    } else if (o[1] < w->gy0 || o[1] >= gy1) t1 = -1;
    if (t0 < t1) {
        double px = o[0] + t0 * dx - w->gx0, py = o[1] + t0 * dy - w->gy0;
        int ix = (int)(px / w->cell), iy = (int)(py / w->cell);
        if (ix >= w->gnx) ix = w->gnx - 1;
        if (iy >= w->gny) iy = w->gny - 1;
        if (ix < 0) ix = 0;
        if (iy < 0) iy = 0;
        int sx = dx > 0 ? 1 : -1, sy = dy > 0 ? 1 : -1;
        double tdx = fabs(dx) > 1e-12 ? w->cell / fabs(dx) : INFINITY;
        double tdy = fabs(dy) > 1e-12 ? w->cell / fabs(dy) : INFINITY;
        double tmx = fabs(dx) > 1e-12 ? ((ix + (sx > 0)) * w->cell - (o[0] - w->gx0)) / dx : INFINITY;
        double tmy = fabs(dy) > 1e-12 ? ((iy + (sy > 0)) * w->cell - (o[1] - w->gy0)) / dy : INFINITY;
        double tin = t0;
        for (;;) {
            int c = iy * w->gnx + ix;
            double tout = fmin(tmx, tmy);
            double za = o[2] + d[2] * tin, zb = o[2] + d[2] * fmin(tout, best);
            if (fmin(za, zb) <= w->cell_maxz[c]) {
                for (int k = w->cell_start[c]; k < w->cell_start[c + 1]; k++) {
                    int id = w->cell_items[k];
                    if (mail[id] == stamp) continue;
                    mail[id] = stamp;
                    const prim_t *p = &w->prims[id];
                    double t = porous && p->kind == PRIM_SPHERE && p->cls == w->foliage_cls
                                   ? ray_canopy(p, o, d, w->foliage_depth_m, ray_key, id) : ray_prim(p, o, d);
                    if (t < best) { best = t; cls = w->prims[id].cls; ground = 0; }
                }
            }
            if (best <= tout) break;
            if (d[2] > 0 && zb > w->max_z) break;   /* above everything from here on */
            tin = tout;
            if (tin >= t1) break;
            if (tmx < tmy) { ix += sx; tmx += tdx; if (ix < 0 || ix >= w->gnx) break; }
            else { iy += sy; tmy += tdy; if (iy < 0 || iy >= w->gny) break; }
        }
    }
    if (ground) cls = ground_class_at(w, o[0] + best * d[0], o[1] + best * d[1]);
    if (cls < 0) return 0;
    hit->t = best;
    hit->cls = cls;
    return 1;
}

/* Distance from p to an oriented box's surface (inside: to its nearest face). */
static double box_distance(const prim_t *b, const double p[3])
{
    double dx = p[0] - b->cx, dy = p[1] - b->cy;
    double u = b->c * dx + b->s * dy, v = -b->s * dx + b->c * dy;   /* in the box's axes */
    double zc = 0.5 * (b->z0 + b->z1), hz = 0.5 * (b->z1 - b->z0);
    double q[3] = {fabs(u) - b->hx, fabs(v) - b->hy, fabs(p[2] - zc) - hz};
    double out = sqrt(fmax(q[0], 0) * fmax(q[0], 0) + fmax(q[1], 0) * fmax(q[1], 0) + fmax(q[2], 0) * fmax(q[2], 0));
    return out > 0 ? out : -fmax(q[0], fmax(q[1], q[2]));
}

static double cylinder_distance(const prim_t *p, const double x[3])
{
    double radial = hypot(x[0] - p->cx, x[1] - p->cy) - p->r;
    double zc = 0.5 * (p->z0 + p->z1), hz = 0.5 * (p->z1 - p->z0), axial = fabs(x[2] - zc) - hz;
    if (radial > 0 || axial > 0) return hypot(fmax(radial, 0), fmax(axial, 0));
    return -fmax(radial, axial);
}

double world_ground_z(const world_t *w, double x, double y)
{
    return w->terrain.enabled ? terrain_height(&w->terrain, x, y) : 0.0;
}

double world_distance(const world_t *w, const double p[3], double cap)
{
    double best = fmin(cap, fabs(p[2] - world_ground_z(w, p[0], p[1])));
    int ix = (int)floor((p[0] - w->gx0) / w->cell), iy = (int)floor((p[1] - w->gy0) / w->cell);
    for (int cy = iy - 1; cy <= iy + 1; cy++)
        for (int cx = ix - 1; cx <= ix + 1; cx++) {
            if (cx < 0 || cy < 0 || cx >= w->gnx || cy >= w->gny) continue;
            int c = cy * w->gnx + cx;
            for (int k = w->cell_start[c]; k < w->cell_start[c + 1]; k++) {
                const prim_t *q = &w->prims[w->cell_items[k]];
                double d = q->kind == PRIM_BOX ? box_distance(q, p)
                         : q->kind == PRIM_CYLINDER ? cylinder_distance(q, p)
                         : fabs(sqrt((p[0] - q->cx) * (p[0] - q->cx) + (p[1] - q->cy) * (p[1] - q->cy) +
                                     (p[2] - q->cz) * (p[2] - q->cz)) - q->r);
                if (d < best) best = d;
            }
        }
    return best;
}
