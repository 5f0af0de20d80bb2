/* The per-command state machine: restarts, backoff, hang verdicts, FAILED. */
#include "proc.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#define US(s) ((int64_t)llround((s) * 1e6))

void sv_proc_init(sv_proc_t *p, const sv_policy_t *policy)
{
    memset(p, 0, sizeof *p);
    p->policy = policy;
    p->state = SV_STOPPED;
    p->last_exit = SV_EXIT_NONE;
    p->module_state = -1;
}

double sv_backoff_s(const sv_policy_t *pol, int failures)
{
    if (failures <= 0) return 0;
    double d = pol->backoff_initial_s * pow(2.0, failures - 1 < 60 ? failures - 1 : 60);
    return d < pol->backoff_max_s ? d : pol->backoff_max_s;
}

const char *sv_state_name(sv_state_t s)
{
    static const char *names[] = { "STOPPED", "WAITING", "STARTING", "RUNNING", "BACKOFF", "STOPPING", "EXITED", "FAILED" };
    return (unsigned)s < 8 ? names[s] : "UNKNOWN";
}

static int running(const sv_proc_t *p) { return p->state == SV_STARTING || p->state == SV_RUNNING; }

static void begin_stop(sv_proc_t *p, int64_t now, int restart, int failure)
{
    p->state = SV_STOPPING;
    p->restart_after_stop = restart;
    p->stop_is_failure = failure;
    p->killed = 0;
    p->term_pending = 1;
    p->stop_deadline_us = now + US(p->policy->stop_timeout_s);
}

/* A failed run: back off, or give up after max_failures in a row. */
static void failed_run(sv_proc_t *p, int64_t now)
{
    int stable = p->started_us && now - p->started_us >= US(p->policy->stable_s);
    p->failures = stable ? 1 : p->failures + 1;
    if (p->failures >= p->policy->max_failures) {
        p->state = SV_FAILED;
        size_t n = strlen(p->detail);
        snprintf(p->detail + n, sizeof p->detail - n, "; FAILED after %d failures in a row (supervisorctl start retries)",
                 p->failures);
        return;
    }
    p->state = SV_BACKOFF;
    p->restart_at_us = now + US(sv_backoff_s(p->policy, p->failures));
}

sv_action_t sv_proc_tick(sv_proc_t *p, int64_t now, int gate_open)
{
    const sv_policy_t *pol = p->policy;
    switch (p->state) {
    case SV_WAITING:
        if (!p->wanted) { p->state = SV_STOPPED; return SV_DO_NOTHING; }
        return gate_open ? SV_DO_START : SV_DO_NOTHING;
    case SV_BACKOFF:
        if (!p->wanted) { p->state = SV_STOPPED; return SV_DO_NOTHING; }
        return now >= p->restart_at_us ? SV_DO_START : SV_DO_NOTHING;
    case SV_STARTING:
    case SV_RUNNING:
        if (pol->heartbeat_s > 0) {
            int64_t grace_end = p->started_us + US(pol->start_grace_s);
            int64_t beat_due = (p->last_status_us ? p->last_status_us : p->started_us) + US(pol->heartbeat_s);
            if (now > grace_end && now > beat_due) {
                snprintf(p->detail, sizeof p->detail, "hang: no STATUS for %.1f s (heartbeat_s %.1f)",
                         (now - (p->last_status_us ? p->last_status_us : p->started_us)) * 1e-6, pol->heartbeat_s);
                begin_stop(p, now, 1, 1);
                p->term_pending = 0;
                return SV_DO_TERM;
            }
        }
        return SV_DO_NOTHING;
    case SV_STOPPING:
        if (p->term_pending) {
            p->term_pending = 0;
            return SV_DO_TERM;
        }
        if (!p->killed && now >= p->stop_deadline_us) {
            p->killed = 1;
            return SV_DO_KILL;
        }
        return SV_DO_NOTHING;
    default:
        return SV_DO_NOTHING;
    }
}

void sv_proc_started(sv_proc_t *p, int32_t pid, int64_t now)
{
    if (p->runs++ > 0) p->restarts++;
    p->pid = pid;
    p->started_us = now;
    p->last_status_us = 0;
    p->beats = 0;
    p->module_state = -1;
    p->state = p->policy->ready == SV_READY_STARTED ? SV_RUNNING : SV_STARTING;
}

void sv_proc_start_failed(sv_proc_t *p, int64_t now, const char *why)
{
    snprintf(p->detail, sizeof p->detail, "cannot start: %s", why);
    p->started_us = now;
    p->pid = 0;
    failed_run(p, now);
}

void sv_proc_exited(sv_proc_t *p, int code, int64_t now)
{
    p->pid = 0;
    p->last_exit = code;
    p->last_exit_us = now;
    p->module_state = -1;
    if (p->state == SV_STOPPING) {
        if (!p->restart_after_stop || !p->wanted) { p->state = SV_STOPPED; return; }
        if (p->stop_is_failure) { failed_run(p, now); return; }
        p->state = SV_BACKOFF;          /* an operator's restart: at once */
        p->restart_at_us = now;
        return;
    }
    if (code >= 0) snprintf(p->detail, sizeof p->detail, "exited with status %d", code);
    else snprintf(p->detail, sizeof p->detail, "killed by signal %d", -code);
    if (code == 0 && p->policy->restart != SV_RESTART_ALWAYS) { p->state = SV_EXITED; return; }
    if (p->policy->restart == SV_RESTART_NEVER) { p->state = SV_EXITED; return; }
    failed_run(p, now);
}

void sv_proc_heartbeat(sv_proc_t *p, int64_t now, int module_state)
{
    p->last_status_us = now;
    p->module_state = module_state;
    if (p->state == SV_STARTING && ++p->beats >= 2) p->state = SV_RUNNING;
}

void sv_proc_start(sv_proc_t *p, int64_t now)
{
    p->wanted = 1;
    if (p->state == SV_STOPPED || p->state == SV_EXITED || p->state == SV_FAILED) {
        if (p->state == SV_FAILED) p->failures = 0;
        p->detail[0] = 0;
        p->state = SV_WAITING;
    } else if (p->state == SV_BACKOFF) {
        p->restart_at_us = now;     /* asked for it: no more waiting */
    } else if (p->state == SV_STOPPING) {
        p->restart_after_stop = 1;
    }
}

void sv_proc_stop(sv_proc_t *p, int64_t now)
{
    p->wanted = 0;
    if (running(p)) { snprintf(p->detail, sizeof p->detail, "stopped by request"); begin_stop(p, now, 0, 0); }
    else if (p->state == SV_STOPPING) p->restart_after_stop = 0;
    else if (p->state == SV_WAITING || p->state == SV_BACKOFF) p->state = SV_STOPPED;
}

void sv_proc_restart(sv_proc_t *p, int64_t now)
{
    if (running(p)) {
        p->wanted = 1;
        snprintf(p->detail, sizeof p->detail, "restarted by request");
        begin_stop(p, now, 1, 0);
    } else {
        if (p->state == SV_FAILED) p->failures = 0;
        sv_proc_start(p, now);
    }
}

int sv_proc_ready(const sv_proc_t *p)
{
    return p->state == SV_RUNNING || (p->state == SV_EXITED && p->last_exit == 0);
}
