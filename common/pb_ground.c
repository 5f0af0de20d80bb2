/* Ground model: the height grid, its files and lookups. */
#include "pb_ground.h"

#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_config.h"

#define SCALE_M 0.001

struct pb_ground {
    double x0, y0, cell;
    int nx, ny;
    float *z;       /* NAN = unknown */
};

pb_ground_t *pb_ground_create(double x0, double y0, double cell, int nx, int ny)
{
    if (!(cell > 0) || nx < 2 || ny < 2 || (size_t)nx * ny > (size_t)1 << 30) return NULL;
    pb_ground_t *g = calloc(1, sizeof *g);
    g->x0 = x0; g->y0 = y0; g->cell = cell; g->nx = nx; g->ny = ny;
    g->z = malloc((size_t)nx * ny * sizeof *g->z);
    for (size_t i = 0; i < (size_t)nx * ny; i++) g->z[i] = NAN;
    return g;
}

void pb_ground_destroy(pb_ground_t *g)
{
    if (!g) return;
    free(g->z);
    free(g);
}

void pb_ground_set(pb_ground_t *g, int ix, int iy, double z)
{
    if (ix >= 0 && iy >= 0 && ix < g->nx && iy < g->ny) g->z[(size_t)iy * g->nx + ix] = (float)z;
}

double pb_ground_get(const pb_ground_t *g, int ix, int iy)
{
    if (ix < 0 || iy < 0 || ix >= g->nx || iy >= g->ny) return NAN;
    return g->z[(size_t)iy * g->nx + ix];
}

void pb_ground_dims(const pb_ground_t *g, double *x0, double *y0, double *cell, int *nx, int *ny)
{
    *x0 = g->x0; *y0 = g->y0; *cell = g->cell; *nx = g->nx; *ny = g->ny;
}

static const char *base_name(const char *p)
{
    const char *s = strrchr(p, '/');
    return s ? s + 1 : p;
}

int pb_ground_save(const pb_ground_t *g, const char *yaml_path, pb_err_t *err)
{
    double lo = INFINITY, hi = -INFINITY;
    size_t N = (size_t)g->nx * g->ny;
    for (size_t i = 0; i < N; i++)
        if (!isnan(g->z[i])) { lo = fmin(lo, g->z[i]); hi = fmax(hi, g->z[i]); }
    if (!isfinite(lo)) lo = hi = 0;
    double z0 = floor(lo * 1000) / 1000;
    if ((hi - z0) / SCALE_M > 65533) return pb_err_set(err, "%s: heights span %.1f m, more than the format's 65.5 m", yaml_path, hi - lo);
    char pgm[1200];
    snprintf(pgm, sizeof pgm, "%s", yaml_path);
    char *dot = strrchr(pgm, '.');
    if (dot && !strchr(dot, '/')) *dot = 0;
    strncat(pgm, ".pgm", sizeof pgm - strlen(pgm) - 1);
    FILE *f = fopen(pgm, "wb");
    if (!f) return pb_err_set(err, "%s: %s", pgm, strerror(errno));
    fprintf(f, "P5\n# portobello ground model: height = z0_m + (v - 1) * scale_m, v = 0 unknown\n%d %d\n65535\n", g->nx, g->ny);
    uint8_t *row = malloc((size_t)g->nx * 2);
    for (int j = 0; j < g->ny; j++) {
        for (int i = 0; i < g->nx; i++) {
            float z = g->z[(size_t)j * g->nx + i];
            long v = isnan(z) ? 0 : lround((z - z0) / SCALE_M) + 1;
            row[2 * i] = (uint8_t)(v >> 8); row[2 * i + 1] = (uint8_t)(v & 0xff);
        }
        fwrite(row, 2, (size_t)g->nx, f);
    }
    free(row);
    if (fclose(f)) return pb_err_set(err, "%s: %s", pgm, strerror(errno));
    f = fopen(yaml_path, "w");
    if (!f) return pb_err_set(err, "%s: %s", yaml_path, strerror(errno));
    fprintf(f, "# Ground model (docs/sites.md): height grid of the drivable and walkable surface.\n"
               "origin_x: %.3f\norigin_y: %.3f\ncell_m: %.3f\nwidth: %d\nheight: %d\nz0_m: %.3f\nscale_m: %.4f\nfile: %s\n",
            g->x0, g->y0, g->cell, g->nx, g->ny, z0, SCALE_M, base_name(pgm));
    if (fclose(f)) return pb_err_set(err, "%s: %s", yaml_path, strerror(errno));
    return 0;
}

/* One header token of a PGM (skipping whitespace and # comments); *off advances. */
static int pgm_token(const uint8_t *b, size_t n, size_t *off, long *out)
{
    size_t i = *off;
    for (;;) {
        while (i < n && (b[i] == ' ' || b[i] == '\t' || b[i] == '\n' || b[i] == '\r')) i++;
        if (i < n && b[i] == '#') { while (i < n && b[i] != '\n') i++; continue; }
        break;
    }
    if (i >= n || b[i] < '0' || b[i] > '9') { *off = i; return -1; }
    long v = 0;
    while (i < n && b[i] >= '0' && b[i] <= '9' && v < 100000000) v = v * 10 + (b[i++] - '0');
    *off = i;
    *out = v;
    return 0;
}

pb_ground_t *pb_ground_load(const char *yaml_path, pb_err_t *err)
{
    pb_cfg_t *cfg = pb_cfg_load(yaml_path, err);
    if (!cfg) return NULL;
    struct { double ox, oy, cell, z0, scale; long w, h; char file[256]; } o = { 0, 0, 0, 0, 0, 0, 0, "" };
#define O(key, type, field, len) { key, type, offsetof(typeof(o), field), len, 1 }
    const pb_cfg_field_t f[] = {
        O("origin_x", PB_CFG_DOUBLE, ox, 0), O("origin_y", PB_CFG_DOUBLE, oy, 0), O("cell_m", PB_CFG_DOUBLE, cell, 0),
        O("width", PB_CFG_INT, w, 0), O("height", PB_CFG_INT, h, 0), O("z0_m", PB_CFG_DOUBLE, z0, 0),
        O("scale_m", PB_CFG_DOUBLE, scale, 0), O("file", PB_CFG_STRING, file, sizeof o.file), PB_CFG_END };
#undef O
    int rc = pb_cfg_read(pb_cfg_root(cfg), f, &o, err);
    int line = pb_node_line(pb_cfg_root(cfg));
    pb_cfg_free(cfg);
    if (rc) return NULL;
    if (!(o.cell > 0 && o.cell < 100) || o.w < 2 || o.h < 2 || o.w * o.h > (1L << 30) || !(o.scale > 0) ||
        !isfinite(o.ox) || !isfinite(o.oy) || !isfinite(o.z0)) {
        pb_err_set(err, "%s:%d: cell_m in (0, 100), width and height >= 2, scale_m > 0 are required", yaml_path, line);
        return NULL;
    }
    char pgm[1400];
    const char *slash = strrchr(yaml_path, '/');
    snprintf(pgm, sizeof pgm, "%.*s%s", slash ? (int)(slash - yaml_path + 1) : 0, yaml_path, o.file);
    FILE *fp = fopen(pgm, "rb");
    if (!fp) { pb_err_set(err, "%s: %s", pgm, strerror(errno)); return NULL; }
    size_t cap = (size_t)o.w * o.h * 2 + 4096, n = 0;
    uint8_t *b = malloc(cap);
    n = fread(b, 1, cap, fp);
    fclose(fp);
    pb_ground_t *g = NULL;
    size_t off = 2;
    long w, h, maxv;
    if (n < 2 || b[0] != 'P' || b[1] != '5') { pb_err_set(err, "%s: byte 0: not a binary PGM (P5)", pgm); goto out; }
    if (pgm_token(b, n, &off, &w) || pgm_token(b, n, &off, &h) || pgm_token(b, n, &off, &maxv)) {
        pb_err_set(err, "%s: byte %zu: bad PGM header", pgm, off); goto out;
    }
    if (w != o.w || h != o.h || maxv != 65535) {
        pb_err_set(err, "%s: header %ldx%ld maxval %ld, expected %ldx%ld maxval 65535 (%s)", pgm, w, h, maxv, o.w, o.h, yaml_path);
        goto out;
    }
    off++;      /* the single whitespace after maxval */
    if (n - off != (size_t)w * h * 2) {
        pb_err_set(err, "%s: byte %zu: %zu bytes of heights, expected %ld", pgm, off, n - off, w * h * 2); goto out;
    }
    g = pb_ground_create(o.ox, o.oy, o.cell, (int)w, (int)h);
    for (size_t i = 0; i < (size_t)w * h; i++) {
        unsigned v = (unsigned)b[off + 2 * i] << 8 | b[off + 2 * i + 1];
        g->z[i] = v ? (float)(o.z0 + (v - 1.0) * o.scale) : NAN;
    }
out:
    free(b);
    return g;
}

int pb_ground_height(const pb_ground_t *g, double x, double y, double *z)
{
    double fx = (x - g->x0) / g->cell, fy = (y - g->y0) / g->cell;
    if (!(fx >= 0 && fy >= 0 && fx <= g->nx - 1 && fy <= g->ny - 1)) return -1;
    int i = (int)fx, j = (int)fy;
    if (i > g->nx - 2) i = g->nx - 2;
    if (j > g->ny - 2) j = g->ny - 2;
    double u = fx - i, v = fy - j, sw = 0, sz = 0;
    const double w[4] = { (1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v };
    const float *h = g->z + (size_t)j * g->nx + i;
    const float c[4] = { h[0], h[1], h[g->nx], h[g->nx + 1] };
    for (int k = 0; k < 4; k++)
        if (!isnan(c[k])) { sw += w[k]; sz += w[k] * c[k]; }
    if (sw < 1e-9) {    /* on a known corner's edge with zero weight: take any known corner */
        for (int k = 0; k < 4; k++) if (!isnan(c[k])) { *z = c[k]; return 0; }
        return -1;
    }
    *z = sz / sw;
    return 0;
}

int pb_ground_car(const pb_ground_t *g, double x, double y, double yaw, double wheelbase, double track,
                  double *z, double *roll, double *pitch)
{
    double c = cos(yaw), s = sin(yaw), h[4];   /* rear left, rear right, front left, front right */
    for (int k = 0; k < 4; k++) {
        double a = (k & 2) ? wheelbase : 0, l = (k & 1) ? -track / 2 : track / 2;
        if (pb_ground_height(g, x + c * a - s * l, y + s * a + c * l, &h[k])) return -1;
    }
    *z = 0.5 * (h[0] + h[1]);
    *pitch = -atan2(0.5 * (h[2] + h[3]) - *z, wheelbase);
    *roll = atan2(0.5 * (h[0] + h[2]) - 0.5 * (h[1] + h[3]), track);
    return 0;
}
