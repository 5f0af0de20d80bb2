/* pb_profile: see pb_profile.h. */
#include "pb_profile.h"

#include <stdlib.h>
#include <string.h>

void pb_profile_sample(const double *kt, const double *kv, int nk, double dt, int n, double *v)
{
    int j = 0;
    for (int k = 0; k < n; k++) {
        double tk = k * dt;
        while (j < nk - 2 && kt[j + 1] <= tk) j++;
        double span = kt[j + 1] - kt[j];
        double f = span > 0 ? (tk - kt[j]) / span : 1;
        if (f > 1) f = 1;
        v[k] = kv[j] + (kv[j + 1] - kv[j]) * f;
    }
}

void pb_profile_smooth(double *v, int n, int w)
{
    double *c = malloc((n + 1) * sizeof *c), *y = malloc(n * sizeof *y);
    c[0] = 0;
    for (int i = 0; i < n; i++) c[i + 1] = c[i] + v[i];
    int h = w / 2;
    for (int i = 0; i < n; i++) {
        int lo = i - h, hi = i + h;     /* inclusive */
        double sum = 0;
        if (lo < 0) { sum += -lo * v[0]; lo = 0; }
        if (hi > n - 1) { sum += (hi - (n - 1)) * v[n - 1]; hi = n - 1; }
        sum += c[hi + 1] - c[lo];
        y[i] = sum / w;
    }
    memcpy(v, y, n * sizeof *v);
    free(y);
    free(c);
}
