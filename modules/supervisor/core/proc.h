/* proc: what the supervisor does with one command, as a pure state machine.
 *
 * The shell feeds it what happened (started, exited, a STATUS heartbeat, an
 * operator's request) with the time on a monotonic clock, and asks it each turn
 * what to do now (start, send SIGTERM to the group, SIGKILL it). No I/O, no clock.
 *
 *   STOPPED --start--> WAITING (group gate closed) --> STARTING --second STATUS--> RUNNING
 *   STARTING/RUNNING --exit--> BACKOFF --delay--> STARTING ...   (or EXITED: exit 0 with
 *       restart on-failure / never)
 *   STARTING/RUNNING --no STATUS for heartbeat_s after start_grace_s--> STOPPING --exit--> BACKOFF
 *   max_failures failures in a row (each run shorter than stable_s) --> FAILED, until
 *       an operator's start or restart
 * Delays double from backoff_initial_s up to backoff_max_s; a run of stable_s or more
 * starts the count again. Ownership: a plain struct the caller owns. */
#ifndef SV_PROC_H
#define SV_PROC_H

#include <stdint.h>

#include "stack.h"

/* Same numbers as portobello_command_state_t STATE_*. */
typedef enum {
    SV_STOPPED = 0, SV_WAITING = 1, SV_STARTING = 2, SV_RUNNING = 3,
    SV_BACKOFF = 4, SV_STOPPING = 5, SV_EXITED = 6, SV_FAILED = 7,
} sv_state_t;

typedef enum { SV_DO_NOTHING, SV_DO_START, SV_DO_TERM, SV_DO_KILL } sv_action_t;

#define SV_EXIT_NONE (-1000)

typedef struct {
    const sv_policy_t *policy;
    sv_state_t state;
    int wanted;             /* the operator wants it running */
    int restart_after_stop; /* STOPPING because of a restart or a hang, not a stop */
    int stop_is_failure;    /* the stop was a hang verdict: counts as a failure */
    int term_pending;       /* STOPPING: SIGTERM not sent yet */
    int killed;             /* SIGKILL already sent in this STOPPING */
    int32_t pid;
    int64_t started_us, stop_deadline_us, restart_at_us, last_status_us, last_exit_us;
    int32_t restarts, failures, last_exit, module_state;
    int runs;               /* runs started; a run after the first is a restart */
    int beats;              /* STATUS heartbeats of this run */
    char detail[256];
} sv_proc_t;

void sv_proc_init(sv_proc_t *p, const sv_policy_t *policy);
/* What to do now. gate_open: the groups before this one are ready. */
sv_action_t sv_proc_tick(sv_proc_t *p, int64_t now, int gate_open);
void sv_proc_started(sv_proc_t *p, int32_t pid, int64_t now);
/* The start failed (fork/exec): counted as a failure. */
void sv_proc_start_failed(sv_proc_t *p, int64_t now, const char *why);
/* exit_code >= 0, or minus the signal that ended it. */
void sv_proc_exited(sv_proc_t *p, int exit_code, int64_t now);
void sv_proc_heartbeat(sv_proc_t *p, int64_t now, int module_state);
/* Operator requests: start (also recovers FAILED), stop, restart. */
void sv_proc_start(sv_proc_t *p, int64_t now);
void sv_proc_stop(sv_proc_t *p, int64_t now);
void sv_proc_restart(sv_proc_t *p, int64_t now);
/* Ready: the groups after this one may start. With ready: status, a module is ready at
 * its second STATUS: the first goes out when its bus opens (it is alive, perhaps still
 * loading a map), the next from its running loop a period later (it is subscribed). */
int sv_proc_ready(const sv_proc_t *p);
/* Delay before the next start after `failures` failures in a row. */
double sv_backoff_s(const sv_policy_t *policy, int failures);
const char *sv_state_name(sv_state_t s);

#endif
