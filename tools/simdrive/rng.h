/* Counter-based random numbers: every draw is a pure function of (seed, stream,
 * a, b), so results do not depend on threading or on the order of generation. */
#ifndef SIM_RNG_H
#define SIM_RNG_H

#include <math.h>
#include <stdint.h>

enum {  /* streams: one per use, so adding a draw never shifts another */
    RNG_LIDAR_NOISE = 1, RNG_LIDAR_DROP, RNG_LIDAR_REFL, RNG_IMU, RNG_IMU_BIAS,
    RNG_GNSS, RNG_CAN_JITTER, RNG_DWELL, RNG_TRAFFIC, RNG_DRIVER, RNG_LEAD, RNG_ACTORS, RNG_FOLIAGE,
};

static inline uint64_t rng_mix(uint64_t z)
{   /* splitmix64 finaliser */
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static inline uint64_t rng_u64(uint64_t seed, uint64_t stream, uint64_t a, uint64_t b)
{
    return rng_mix(rng_mix(rng_mix(seed ^ (stream << 56)) ^ a) ^ b);
}

/* Uniform in [0, 1). */
static inline double rng_uniform(uint64_t seed, uint64_t stream, uint64_t a, uint64_t b)
{
    return (double)(rng_u64(seed, stream, a, b) >> 11) * (1.0 / 9007199254740992.0);
}

/* Standard normal (Box-Muller over two independent draws). */
static inline double rng_gauss(uint64_t seed, uint64_t stream, uint64_t a, uint64_t b)
{
    uint64_t h1 = rng_u64(seed, stream, a, 2 * b), h2 = rng_u64(seed, stream, a, 2 * b + 1);
    double u1 = ((double)(h1 >> 11) + 0.5) * (1.0 / 9007199254740992.0);
    double u2 = (double)(h2 >> 11) * (1.0 / 9007199254740992.0);
    return sqrt(-2.0 * log(u1)) * cos(2.0 * M_PI * u2);
}

#endif
