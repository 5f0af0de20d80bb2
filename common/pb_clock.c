#include "pb_clock.h"

#include <time.h>

static int64_t utime_of(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static double ms_of(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

int64_t pb_clock_wall_utime(void) { return utime_of(CLOCK_REALTIME); }
int64_t pb_clock_monotonic_utime(void) { return utime_of(CLOCK_MONOTONIC); }
double pb_clock_monotonic_ms(void) { return ms_of(CLOCK_MONOTONIC); }
double pb_clock_thread_cpu_ms(void) { return ms_of(CLOCK_THREAD_CPUTIME_ID); }
double pb_clock_process_cpu_ms(void) { return ms_of(CLOCK_PROCESS_CPUTIME_ID); }
