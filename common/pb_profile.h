/* pb_profile: speed profiles sampled in time, shared by simdrive's road drive and the
 * lab twin's legs so that both platforms plan speed the same way. */
#ifndef PB_PROFILE_H
#define PB_PROFILE_H

#ifdef __cplusplus
extern "C" {
#endif

/* v[k] (k < n) = the piecewise-linear speed through the knots (kt[i], kv[i]),
 * i < nk (nk >= 2, kt rising), at time k * dt; held at the last knot after it. */
void pb_profile_sample(const double *kt, const double *kv, int nk, double dt, int n, double *v);

/* A centred moving average over w samples (w odd), the ends extended by their
 * values. Applied twice it is a triangular window: acceleration becomes continuous
 * and jerk bounded. */
void pb_profile_smooth(double *v, int n, int w);

#ifdef __cplusplus
}
#endif
#endif
