/* pb_clock_offset: a device's clock against the sensors' (see pb_clock_offset.h). */
#include "pb_clock_offset.h"

#include <stdlib.h>

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

int64_t pb_clock_offset_median(int64_t *lags, size_t n, int64_t tol_us)
{
    if (n == 0) return 0;
    qsort(lags, n, sizeof *lags, cmp_i64);
    int64_t med = lags[n / 2];
    return llabs(med) <= tol_us ? 0 : med;
}

void pb_clock_offset_init(pb_clock_offset_t *c, int64_t tol_us)
{
    *c = (pb_clock_offset_t){ .tol_us = tol_us };
}

void pb_clock_offset_forget(pb_clock_offset_t *c)
{
    c->n = c->next = 0;
}

int pb_clock_offset_add(pb_clock_offset_t *c, int64_t stamp, int64_t newest)
{
    if (newest == 0) return 0;
    c->lag[c->next] = stamp - newest;
    c->next = (c->next + 1) % PB_CLOCK_OFFSET_LAGS;
    if (c->n < PB_CLOCK_OFFSET_LAGS) c->n++;
    if (c->n < PB_CLOCK_OFFSET_MIN) return 0;
    int64_t v[PB_CLOCK_OFFSET_LAGS];
    for (int i = 0; i < c->n; i++) v[i] = c->lag[i];
    c->offset = pb_clock_offset_median(v, (size_t)c->n, c->tol_us);
    if (llabs(c->offset - c->reported) <= c->tol_us) return 0;
    c->reported = c->offset;
    return 1;
}
