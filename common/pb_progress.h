/* pb_progress: a progress bar on stderr for long work. On a terminal it redraws
 * one line; otherwise it prints a line every 10 %. Quiet if disabled. */
#ifndef PB_PROGRESS_H
#define PB_PROGRESS_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    const char *label;
    int64_t total;
    int64_t done;
    int last_permille;
    int tty;
    int quiet;
    double t_start;
} pb_progress_t;

void pb_progress_start(pb_progress_t *p, const char *label, int64_t total, int quiet);
void pb_progress_update(pb_progress_t *p, int64_t done);
void pb_progress_finish(pb_progress_t *p);

#ifdef __cplusplus
}
#endif
#endif
