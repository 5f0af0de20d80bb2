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
#define B PB_GROUND_BLOCK
#define BB ((size_t)B * B)

/* The blocks held, in an open-addressed hash table keyed by by * nbx + bx + 1 (0: empty
 * slot): memory follows the known ground, a lookup costs a hash and a probe or two. */
struct pb_ground {
    double x0, y0, cell;
    int nx, ny, nbx, nby;
    size_t nblocks, cap;    /* cap: a power of two, at most half full */
    int64_t *keys;
    float **blocks;         /* BB floats each, NAN = unknown */
    int lost;               /* a block could not be allocated: heights were dropped (save refuses) */
};

static size_t slot_of(const pb_ground_t *g, int64_t key)
{
    size_t i = (size_t)(((uint64_t)key * 0x9E3779B97F4A7C15ull) >> 20) & (g->cap - 1);
    while (g->keys[i] && g->keys[i] != key) i = (i + 1) & (g->cap - 1);
    return i;
}

pb_ground_t *pb_ground_create(double x0, double y0, double cell, int nx, int ny)
{
    if (!(cell > 0) || nx < 2 || ny < 2 || nx > (1 << 28) || ny > (1 << 28)) return NULL;
    pb_ground_t *g = calloc(1, sizeof *g);
    if (!g) return NULL;
    g->x0 = x0; g->y0 = y0; g->cell = cell; g->nx = nx; g->ny = ny;
    g->nbx = (nx + B - 1) / B; g->nby = (ny + B - 1) / B;
    g->cap = 16;
    g->keys = calloc(g->cap, sizeof *g->keys);
    g->blocks = calloc(g->cap, sizeof *g->blocks);
    if (!g->keys || !g->blocks) { pb_ground_destroy(g); return NULL; }
    return g;
}

void pb_ground_destroy(pb_ground_t *g)
{
    if (!g) return;
    for (size_t i = 0; i < g->cap && g->blocks; i++) free(g->blocks[i]);
    free(g->blocks);
    free(g->keys);
    free(g);
}

const float *pb_ground_block(const pb_ground_t *g, int bx, int by)
{
    if (bx < 0 || by < 0 || bx >= g->nbx || by >= g->nby) return NULL;
    return g->blocks[slot_of(g, (int64_t)by * g->nbx + bx + 1)];
}

float *pb_ground_block_make(pb_ground_t *g, int bx, int by)
{
    if (bx < 0 || by < 0 || bx >= g->nbx || by >= g->nby) return NULL;
    const int64_t key = (int64_t)by * g->nbx + bx + 1;
    size_t i = slot_of(g, key);
    if (g->keys[i]) return g->blocks[i];
    if (2 * (g->nblocks + 1) > g->cap) {    /* grow: rehash into twice the slots */
        pb_ground_t t = *g;
        t.cap = 2 * g->cap;
        t.keys = calloc(t.cap, sizeof *t.keys);
        t.blocks = calloc(t.cap, sizeof *t.blocks);
        if (!t.keys || !t.blocks) { free(t.keys); free(t.blocks); g->lost = 1; return NULL; }
        for (size_t k = 0; k < g->cap; k++)
            if (g->keys[k]) {
                size_t s = slot_of(&t, g->keys[k]);
                t.keys[s] = g->keys[k];
                t.blocks[s] = g->blocks[k];
            }
        free(g->keys); free(g->blocks);
        *g = t;
        i = slot_of(g, key);
    }
    float *b = malloc(BB * sizeof *b);
    if (!b) { g->lost = 1; return NULL; }
    for (size_t k = 0; k < BB; k++) b[k] = NAN;
    g->keys[i] = key;
    g->blocks[i] = b;
    g->nblocks++;
    return b;
}

static int cmp_key(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

size_t pb_ground_blocks(const pb_ground_t *g, int *bxy)
{
    if (!bxy) return g->nblocks;
    int64_t *k = malloc((g->nblocks + 1) * sizeof *k);
    size_t n = 0;
    for (size_t i = 0; i < g->cap; i++) if (g->keys[i]) k[n++] = g->keys[i] - 1;
    qsort(k, n, sizeof *k, cmp_key);
    for (size_t i = 0; i < n; i++) { bxy[2 * i] = (int)(k[i] % g->nbx); bxy[2 * i + 1] = (int)(k[i] / g->nbx); }
    free(k);
    return n;
}

void pb_ground_set(pb_ground_t *g, int ix, int iy, double z)
{
    if (ix < 0 || iy < 0 || ix >= g->nx || iy >= g->ny) return;
    float *b = isnan(z) ? (float *)pb_ground_block(g, ix / B, iy / B) : pb_ground_block_make(g, ix / B, iy / B);
    if (b) b[(size_t)(iy % B) * B + ix % B] = (float)z;
}

double pb_ground_get(const pb_ground_t *g, int ix, int iy)
{
    if (ix < 0 || iy < 0 || ix >= g->nx || iy >= g->ny) return NAN;
    const float *b = pb_ground_block(g, ix / B, iy / B);
    return b ? b[(size_t)(iy % B) * B + ix % B] : NAN;
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

/* The blocked file: magic, then per block held bx, by (int32), B x B values (uint16,
 * the PGM's coding), FNV-1a 64 of the record so far; all little-endian. */
static const char BLOCKS_MAGIC[8] = { 'P', 'B', 'G', 'R', 'B', 'L', 'K', '1' };
#define RECORD_BYTES (8 + 2 * BB + 8)

static uint64_t fnv1a64(const uint8_t *b, size_t n)    /* as pb_bytes.h's (C here) */
{
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < n; i++) h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

static void put_le(uint8_t *p, uint64_t v, int n)
{
    for (int i = 0; i < n; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static uint64_t get_le(const uint8_t *p, int n)
{
    uint64_t v = 0;
    for (int i = n - 1; i >= 0; i--) v = v << 8 | p[i];
    return v;
}

/* YAML_PATH with its extension replaced by EXT. */
static void sibling(const char *yaml_path, const char *ext, char *out, size_t len)
{
    snprintf(out, len, "%s", yaml_path);
    char *dot = strrchr(out, '.');
    if (dot && !strchr(dot, '/')) *dot = 0;
    strncat(out, ext, len - strlen(out) - 1);
}

/* Corners beyond width or height in a block on the grid's edge: never known (a caller of
 * pb_ground_block_make may have written them). */
static int inside(const pb_ground_t *g, int x, int y)
{
    return x < g->nx && y < g->ny;
}

static long code(float z, double z0)
{
    return isnan(z) ? 0 : lround((z - z0) / SCALE_M) + 1;
}

int pb_ground_save(const pb_ground_t *g, const char *yaml_path, pb_err_t *err)
{
    if (g->lost) return pb_err_set(err, "%s: not written: out of memory while the ground model was made (heights lost)", yaml_path), -1;
    /* the heights' range over the blocks held, and which hold a known corner */
    size_t n = pb_ground_blocks(g, NULL), kept = 0;
    int *bxy = malloc((2 * n + 1) * sizeof *bxy);
    pb_ground_blocks(g, bxy);
    double lo = INFINITY, hi = -INFINITY;
    for (size_t k = 0; k < n; k++) {
        const float *b = pb_ground_block(g, bxy[2 * k], bxy[2 * k + 1]);
        int known = 0;
        for (size_t i = 0; i < BB; i++)
            if (!isnan(b[i]) && inside(g, bxy[2 * k] * B + (int)(i % B), bxy[2 * k + 1] * B + (int)(i / B))) {
                lo = fmin(lo, b[i]); hi = fmax(hi, b[i]); known = 1;
            }
        if (known) { bxy[2 * kept] = bxy[2 * k]; bxy[2 * kept + 1] = bxy[2 * k + 1]; kept++; }
    }
    if (!isfinite(lo)) lo = hi = 0;
    double z0 = floor(lo * 1000) / 1000;
    if ((hi - z0) / SCALE_M > 65533) {
        free(bxy);
        return pb_err_set(err, "%s: heights span %.1f m, more than the format's 65.5 m", yaml_path, hi - lo);
    }
    /* a large grid or one mostly unknown: the blocks; else the PGM (every corner) */
    const int blocked = (long)g->nx * g->ny > PB_GROUND_DENSE_MAX || 4 * (long)kept < (long)g->nbx * g->nby;
    char data[1200];
    sibling(yaml_path, blocked ? ".blocks" : ".pgm", data, sizeof data);
    FILE *f = fopen(data, "wb");
    if (!f) { free(bxy); return pb_err_set(err, "%s: %s", data, strerror(errno)); }
    if (blocked) {
        uint8_t *rec = malloc(RECORD_BYTES);
        fwrite(BLOCKS_MAGIC, 1, sizeof BLOCKS_MAGIC, f);
        for (size_t k = 0; k < kept; k++) {
            const float *b = pb_ground_block(g, bxy[2 * k], bxy[2 * k + 1]);
            put_le(rec, (uint32_t)bxy[2 * k], 4);
            put_le(rec + 4, (uint32_t)bxy[2 * k + 1], 4);
            for (size_t i = 0; i < BB; i++) {
                int in = inside(g, bxy[2 * k] * B + (int)(i % B), bxy[2 * k + 1] * B + (int)(i / B));
                put_le(rec + 8 + 2 * i, in ? (uint64_t)code(b[i], z0) : 0, 2);
            }
            put_le(rec + 8 + 2 * BB, fnv1a64(rec, 8 + 2 * BB), 8);
            fwrite(rec, 1, RECORD_BYTES, f);
        }
        free(rec);
    } else {
        fprintf(f, "P5\n# portobello ground model: height = z0_m + (v - 1) * scale_m, v = 0 unknown\n%d %d\n65535\n", g->nx, g->ny);
        uint8_t *row = malloc((size_t)g->nx * 2);
        for (int j = 0; j < g->ny; j++) {
            for (int bx = 0; bx < g->nbx; bx++) {
                const float *b = pb_ground_block(g, bx, j / B);
                for (int i = bx * B; i < g->nx && i < (bx + 1) * B; i++) {
                    long v = b ? code(b[(size_t)(j % B) * B + i % B], z0) : 0;
                    row[2 * i] = (uint8_t)(v >> 8); row[2 * i + 1] = (uint8_t)(v & 0xff);
                }
            }
            fwrite(row, 2, (size_t)g->nx, f);
        }
        free(row);
    }
    free(bxy);
    if (fclose(f)) return pb_err_set(err, "%s: %s", data, strerror(errno));
    f = fopen(yaml_path, "w");
    if (!f) return pb_err_set(err, "%s: %s", yaml_path, strerror(errno));
    fprintf(f, "# Ground model (docs/sites.md): height grid of the drivable and walkable surface.\n"
               "origin_x: %.3f\norigin_y: %.3f\ncell_m: %.3f\nwidth: %d\nheight: %d\nz0_m: %.3f\nscale_m: %.4f\n",
            g->x0, g->y0, g->cell, g->nx, g->ny, z0, SCALE_M);
    if (blocked) fprintf(f, "block: %d\nblocks: %zu\n", B, kept);
    fprintf(f, "file: %s\n", base_name(data));
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

typedef struct { double ox, oy, cell, z0, scale; long w, h, block, blocks; char file[256]; } header_t;

static float height_of(unsigned v, const header_t *o)
{
    return v ? (float)(o->z0 + (v - 1.0) * o->scale) : NAN;
}

static long file_size(FILE *fp)
{
    if (fseek(fp, 0, SEEK_END)) return -1;
    long n = ftell(fp);
    rewind(fp);
    return n;
}

/* The PGM, a row at a time into the blocks (only those with a known corner made). */
static pb_ground_t *load_pgm(FILE *fp, const char *pgm, const char *yaml_path, const header_t *o, pb_err_t *err)
{
    uint8_t head[4096];
    long size = file_size(fp);
    size_t n = fread(head, 1, sizeof head, fp), off = 2;
    long w, h, maxv;
    if (n < 2 || head[0] != 'P' || head[1] != '5') { pb_err_set(err, "%s: byte 0: not a binary PGM (P5)", pgm); return NULL; }
    if (pgm_token(head, n, &off, &w) || pgm_token(head, n, &off, &h) || pgm_token(head, n, &off, &maxv)) {
        pb_err_set(err, "%s: byte %zu: bad PGM header", pgm, off);
        return NULL;
    }
    if (w != o->w || h != o->h || maxv != 65535) {
        pb_err_set(err, "%s: header %ldx%ld maxval %ld, expected %ldx%ld maxval 65535 (%s)", pgm, w, h, maxv, o->w, o->h, yaml_path);
        return NULL;
    }
    off++;      /* the single whitespace after maxval */
    if (size < 0 || (size_t)size < off || (size_t)size - off != (size_t)w * h * 2) {
        pb_err_set(err, "%s: byte %zu: %ld bytes of heights, expected %ld", pgm, off, size - (long)off, w * h * 2);
        return NULL;
    }
    pb_ground_t *g = pb_ground_create(o->ox, o->oy, o->cell, (int)w, (int)h);
    uint8_t *row = malloc((size_t)w * 2);
    if (!g || !row || fseek(fp, (long)off, SEEK_SET)) { pb_err_set(err, "%s: out of memory", pgm); goto fail; }
    for (int j = 0; j < h; j++) {
        if (fread(row, 2, (size_t)w, fp) != (size_t)w) {
            pb_err_set(err, "%s: byte %zu: cannot read row %d", pgm, off + (size_t)j * w * 2, j);
            goto fail;
        }
        for (int i = 0; i < w; i++) {
            unsigned v = (unsigned)row[2 * i] << 8 | row[2 * i + 1];
            if (v) pb_ground_set(g, i, j, height_of(v, o));
        }
    }
    free(row);
    return g;
fail:
    free(row);
    pb_ground_destroy(g);
    return NULL;
}

/* The blocked file: every record checked (place, order, corners beyond the grid, checksum). */
static pb_ground_t *load_blocks(FILE *fp, const char *path, const header_t *o, pb_err_t *err)
{
    long size = file_size(fp);
    uint8_t magic[sizeof BLOCKS_MAGIC];
    if (fread(magic, 1, sizeof magic, fp) != sizeof magic || memcmp(magic, BLOCKS_MAGIC, sizeof magic)) {
        pb_err_set(err, "%s: byte 0: not a ground model's blocks (PBGRBLK1)", path);
        return NULL;
    }
    if (size < 0 || (size_t)size != sizeof magic + (size_t)o->blocks * RECORD_BYTES) {
        pb_err_set(err, "%s: byte %zu: %ld bytes of blocks, expected %ld (%ld blocks)", path, sizeof magic,
                   size - (long)sizeof magic, o->blocks * (long)RECORD_BYTES, o->blocks);
        return NULL;
    }
    pb_ground_t *g = pb_ground_create(o->ox, o->oy, o->cell, (int)o->w, (int)o->h);
    uint8_t *rec = malloc(RECORD_BYTES);
    if (!g || !rec) { pb_err_set(err, "%s: out of memory", path); goto fail; }
    int64_t last = -1;
    for (long k = 0; k < o->blocks; k++) {
        size_t at = sizeof magic + (size_t)k * RECORD_BYTES;
        if (fread(rec, 1, RECORD_BYTES, fp) != RECORD_BYTES) { pb_err_set(err, "%s: byte %zu: cannot read", path, at); goto fail; }
        if (get_le(rec + 8 + 2 * BB, 8) != fnv1a64(rec, 8 + 2 * BB)) {
            pb_err_set(err, "%s: byte %zu: block %ld: checksum does not match (damaged)", path, at, k);
            goto fail;
        }
        long bx = (int32_t)get_le(rec, 4), by = (int32_t)get_le(rec + 4, 4);
        int64_t key = (int64_t)by * g->nbx + bx;
        if (bx < 0 || by < 0 || bx >= g->nbx || by >= g->nby || key <= last) {
            pb_err_set(err, "%s: byte %zu: block (%ld, %ld) outside the %dx%d blocks or not after the one before", path,
                       at, bx, by, g->nbx, g->nby);
            goto fail;
        }
        last = key;
        float *b = pb_ground_block_make(g, (int)bx, (int)by);
        if (!b) { pb_err_set(err, "%s: out of memory", path); goto fail; }
        for (size_t i = 0; i < BB; i++) {
            unsigned v = (unsigned)get_le(rec + 8 + 2 * i, 2);
            long x = bx * B + (long)(i % B), y = by * B + (long)(i / B);
            if (v && (x >= o->w || y >= o->h)) {
                pb_err_set(err, "%s: byte %zu: corner (%ld, %ld) known beyond the grid's %ldx%ld", path, at + 8 + 2 * i,
                           x, y, o->w, o->h);
                goto fail;
            }
            b[i] = height_of(v, o);
        }
    }
    free(rec);
    return g;
fail:
    free(rec);
    pb_ground_destroy(g);
    return NULL;
}

pb_ground_t *pb_ground_load(const char *yaml_path, pb_err_t *err)
{
    pb_cfg_t *cfg = pb_cfg_load(yaml_path, err);
    if (!cfg) return NULL;
    header_t o = { 0, 0, 0, 0, 0, 0, 0, 0, -1, "" };
#define O(key, type, field, len, req) { key, type, offsetof(header_t, field), len, req }
    const pb_cfg_field_t f[] = {
        O("origin_x", PB_CFG_DOUBLE, ox, 0, 1), O("origin_y", PB_CFG_DOUBLE, oy, 0, 1), O("cell_m", PB_CFG_DOUBLE, cell, 0, 1),
        O("width", PB_CFG_INT, w, 0, 1), O("height", PB_CFG_INT, h, 0, 1), O("z0_m", PB_CFG_DOUBLE, z0, 0, 1),
        O("scale_m", PB_CFG_DOUBLE, scale, 0, 1), O("block", PB_CFG_INT, block, 0, 0), O("blocks", PB_CFG_INT, blocks, 0, 0),
        O("file", PB_CFG_STRING, file, sizeof o.file, 1), PB_CFG_END };
#undef O
    int rc = pb_cfg_read(pb_cfg_root(cfg), f, &o, err);
    int line = pb_node_line(pb_cfg_root(cfg));
    pb_cfg_free(cfg);
    if (rc) return NULL;
    const int blocked = o.block != 0;
    if (!(o.cell > 0 && o.cell < 100) || o.w < 2 || o.h < 2 || o.w > (1L << 28) || o.h > (1L << 28) ||
        (!blocked && o.w * o.h > (1L << 30)) || !(o.scale > 0) || !isfinite(o.ox) || !isfinite(o.oy) || !isfinite(o.z0)) {
        pb_err_set(err, "%s:%d: cell_m in (0, 100), width and height >= 2 (a PGM's at most 2^30 corners), scale_m > 0 are required",
                   yaml_path, line);
        return NULL;
    }
    if (blocked && o.blocks == -1) {
        pb_err_set(err, "%s:%d: block without blocks (how many the file holds)", yaml_path, line);
        return NULL;
    }
    if (blocked && (o.block != B || o.blocks < 0 || o.blocks > ((o.w + B - 1) / B) * ((o.h + B - 1) / B))) {
        pb_err_set(err, "%s:%d: block must be %d and blocks from 0 to the grid's blocks (block %ld, blocks %ld)", yaml_path, line,
                   B, o.block, o.blocks);
        return NULL;
    }
    if (!blocked && o.blocks != -1) {
        pb_err_set(err, "%s:%d: blocks without block", yaml_path, line);
        return NULL;
    }
    char data[1400];
    const char *slash = strrchr(yaml_path, '/');
    snprintf(data, sizeof data, "%.*s%s", slash ? (int)(slash - yaml_path + 1) : 0, yaml_path, o.file);
    FILE *fp = fopen(data, "rb");
    if (!fp) { pb_err_set(err, "%s: %s", data, strerror(errno)); return NULL; }
    pb_ground_t *g = blocked ? load_blocks(fp, data, &o, err) : load_pgm(fp, data, yaml_path, &o, err);
    fclose(fp);
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
    float c[4];
    const float *b = pb_ground_block(g, i / B, j / B);
    if (i % B < B - 1 && j % B < B - 1) {   /* the cell inside one block: one look-up */
        const float *h = b ? b + (size_t)(j % B) * B + i % B : NULL;
        for (int k = 0; k < 4; k++) c[k] = h ? h[(k >> 1) * B + (k & 1)] : NAN;
    } else {
        for (int k = 0; k < 4; k++) c[k] = (float)pb_ground_get(g, i + (k & 1), j + (k >> 1));
    }
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
