/* pb_clock: the host's clocks, read in one place.
 *
 * Module logic takes its time from messages (pb_bus_now in replay); these are for the
 * shells' live timestamps, live timers and measuring the cost of work:
 *   wall       CLOCK_REALTIME: a receive time to publish (may step: NTP, GNSS sync)
 *   monotonic  CLOCK_MONOTONIC: timers and elapsed time (never steps)
 *   thread CPU CLOCK_THREAD_CPUTIME_ID: the work one thread did, whatever else the
 *              machine runs (benchmarks on a shared machine)
 *   process CPU CLOCK_PROCESS_CPUTIME_ID: the same for the whole process */
#ifndef PB_CLOCK_H
#define PB_CLOCK_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

int64_t pb_clock_wall_utime(void);
int64_t pb_clock_monotonic_utime(void);
double  pb_clock_monotonic_ms(void);
double  pb_clock_thread_cpu_ms(void);
double  pb_clock_process_cpu_ms(void);

#ifdef __cplusplus
}
#endif
#endif
