/* LIDAR_SCAN (either form) to points in the lidar frame; the model is documented
 * in lcmtypes/lidar_scan_t.lcm. */
#include "pb_scan.h"

#include <math.h>
#include <stdlib.h>

static int reserve(pb_points_t *p, int n)
{
    if (n <= p->cap) return 0;
    float *x = realloc(p->x, n * sizeof *x); if (x) p->x = x;
    float *y = realloc(p->y, n * sizeof *y); if (y) p->y = y;
    float *z = realloc(p->z, n * sizeof *z); if (z) p->z = z;
    float *in = realloc(p->intensity, n * sizeof *in); if (in) p->intensity = in;
    int32_t *t = realloc(p->offset_us, n * sizeof *t); if (t) p->offset_us = t;
    uint8_t *r = realloc(p->ring, n * sizeof *r); if (r) p->ring = r;
    if (!x || !y || !z || !in || !t || !r) return -1;
    p->cap = n;
    return 0;
}

void pb_points_free(pb_points_t *p)
{
    free(p->x); free(p->y); free(p->z); free(p->intensity); free(p->offset_us); free(p->ring);
    *p = (pb_points_t){ 0 };
}

static int range_image(const portobello_lidar_scan_t *s, pb_points_t *out, pb_err_t *err)
{
    if (s->rows <= 0 || s->cols <= 0 || s->npixels != s->rows * s->cols)
        return pb_err_set(err, "LIDAR_SCAN: npixels %d != rows %d x cols %d", s->npixels, s->rows, s->cols);
    if (s->rows > 255) return pb_err_set(err, "LIDAR_SCAN: %d rows (at most 255 beams)", s->rows);
    if (reserve(out, s->npixels) != 0) return pb_err_set(err, "LIDAR_SCAN: out of memory");
    const double *M = s->lidar_from_beam;
    int identity = 1;
    static const double I[16] = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 };
    for (int i = 0; i < 16; i++) if (M[i] != I[i]) identity = 0;
    double n = s->beam_origin_m;
    /* the beams' angles once per sweep, not per pixel: cos and sin of th = enc + azimuth by
     * the angle sum (sin and cos were an eighth of a mapper's time) */
    double ca[255], sa[255], cp[255], sp[255];
    for (int r = 0; r < s->rows; r++) {
        ca[r] = cos(s->beam_azimuth_rad[r]); sa[r] = sin(s->beam_azimuth_rad[r]);
        cp[r] = cos(s->beam_altitude_rad[r]); sp[r] = sin(s->beam_altitude_rad[r]);
    }
    int k = 0;
    for (int c = 0; c < s->cols; c++) {
        double enc = 2 * M_PI * (1.0 - (double)c / s->cols);
        double ce = cos(enc), se = sin(enc);
        for (int r = 0; r < s->rows; r++) {
            int32_t mm = s->range_mm[r * s->cols + c];
            if (mm <= 0) continue;
            double R = mm * 1e-3;
            double cth = ce * ca[r] - se * sa[r], sth = se * ca[r] + ce * sa[r];
            double x = (R - n) * cth * cp[r] + n * ce;
            double y = (R - n) * sth * cp[r] + n * se;
            double z = (R - n) * sp[r];
            if (!identity) {
                double X = M[0] * x + M[1] * y + M[2] * z + M[3];
                double Y = M[4] * x + M[5] * y + M[6] * z + M[7];
                double Z = M[8] * x + M[9] * y + M[10] * z + M[11];
                x = X; y = Y; z = Z;
            }
            float fx = (float)x, fy = (float)y, fz = (float)z;   /* a huge finite double is an infinite float */
            if (!isfinite(fx) || !isfinite(fy) || !isfinite(fz)) continue;
            out->x[k] = fx; out->y[k] = fy; out->z[k] = fz;
            out->intensity[k] = s->reflectivity[r * s->cols + c];
            out->offset_us[k] = s->col_offset_us[c];
            out->ring[k] = (uint8_t)r;
            k++;
        }
    }
    out->n = k;
    return k;
}

int pb_scan_points(const portobello_lidar_scan_t *s, pb_points_t *out, pb_err_t *err)
{
    out->n = 0;
    if (s->npixels > 0 && s->npoints > 0)
        return pb_err_set(err, "LIDAR_SCAN: both a range image (%d pixels) and %d points", s->npixels, s->npoints);
    if (s->npixels > 0) return range_image(s, out, err);
    if (s->npoints < 0) return pb_err_set(err, "LIDAR_SCAN: negative point count %d", s->npoints);
    if (reserve(out, s->npoints > 0 ? s->npoints : 1) != 0) return pb_err_set(err, "LIDAR_SCAN: out of memory");
    int k = 0;
    for (int i = 0; i < s->npoints; i++) {
        if (!isfinite(s->x[i]) || !isfinite(s->y[i]) || !isfinite(s->z[i])) continue;
        if (s->x[i] == 0 && s->y[i] == 0 && s->z[i] == 0) continue;   /* no return (organized clouds) */
        out->x[k] = s->x[i]; out->y[k] = s->y[i]; out->z[k] = s->z[i];
        out->intensity[k] = s->intensity[i];
        out->offset_us[k] = s->point_offset_us[i];
        out->ring[k] = s->ring[i];
        k++;
    }
    out->n = k;
    return k;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Largest gap between neighbouring values of v[0..n-1] (sorted in place). */
static double largest_gap(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    double g = 0;
    for (int i = 1; i < n; i++)
        if (v[i] - v[i - 1] > g) g = v[i] - v[i - 1];
    return g;
}

/* The gaps of nr ring elevations and cols columns a turn; 0 (outputs untouched) when they are not known. */
static int gaps_of(double *alt, int nr, int cols, double *ring_gap_rad, double *col_gap_rad)
{
    double g = nr >= 2 ? largest_gap(alt, nr) : 0;
    if (!(g > 0) || cols <= 0) return 0;
    *ring_gap_rad = g;
    *col_gap_rad = 2 * M_PI / cols;
    return 1;
}

int pb_scan_beam_gaps(const portobello_lidar_scan_t *s, const pb_points_t *pts, double *ring_gap_rad, double *col_gap_rad)
{
    enum { RINGS = 255, SAMPLES = 65, MIN_POINTS = 16 };
    double alt[RINGS];
    int nr = 0;
    if (s->rows >= 2 && s->cols > 0 && s->npixels == s->rows * s->cols) {
        for (int r = 0; r < s->rows && nr < RINGS; r++)
            if (fabsf(s->beam_altitude_rad[r]) <= (float)(M_PI / 2)) alt[nr++] = s->beam_altitude_rad[r];   /* false for NaN */
        return gaps_of(alt, nr, s->cols, ring_gap_rad, col_gap_rad);
    }
    /* point form: each ring's elevation is the median of SAMPLES of its points, spread over the ring */
    int count[RINGS] = { 0 }, most = 0;
    for (int i = 0; i < pts->n; i++)
        if (pts->ring[i] < RINGS) count[pts->ring[i]]++;
    double *el = malloc(sizeof(double) * RINGS * SAMPLES);
    int taken[RINGS] = { 0 }, seen[RINGS] = { 0 };
    if (!el) return 0;
    for (int i = 0; i < pts->n; i++) {
        int r = pts->ring[i];
        if (r >= RINGS || count[r] < MIN_POINTS) continue;
        /* every (count / SAMPLES)-th point of the ring */
        if ((long)seen[r]++ * SAMPLES / count[r] < (long)taken[r] || taken[r] >= SAMPLES) continue;
        el[r * SAMPLES + taken[r]++] = atan2(pts->z[i], hypot(pts->x[i], pts->y[i]));
    }
    for (int r = 0; r < RINGS; r++) {
        if (count[r] < MIN_POINTS || taken[r] == 0) continue;
        double *v = el + r * SAMPLES;
        qsort(v, (size_t)taken[r], sizeof *v, cmp_double);
        alt[nr++] = v[taken[r] / 2];
        if (count[r] > most) most = count[r];
    }
    free(el);
    return gaps_of(alt, nr, most, ring_gap_rad, col_gap_rad);
}
