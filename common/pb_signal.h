/* pb_signal: SIGINT/SIGTERM ask a module to stop cleanly (logs flushed, last
 * STATUS sent). A second signal exits at once. */
#ifndef PB_SIGNAL_H
#define PB_SIGNAL_H

#ifdef __cplusplus
extern "C" {
#endif

void pb_signal_install(void);
int pb_signal_stop_requested(void);

#ifdef __cplusplus
}
#endif
#endif
