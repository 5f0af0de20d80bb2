/* supervisor: starts the commands of a stack file and keeps them running.
 *   supervisor --config stacks/replay.yaml [--set NAME=VALUE ...] [--lcm-url URL]
 * The shell: processes (fork, exec, process groups, signals), output capture and
 * rotation, /proc figures, LCM (STATUS in; SUPERVISOR out; SUPERVISOR_COMMAND in).
 * What to do with each command is decided by core/proc.c. See docs/supervisor.md. */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "core/proc.h"
#include "core/stack.h"
#include "pb_bus.h"
#include "pb_opt.h"
#include "pb_status.h"
#include "portobello_status_t.h"
#include "portobello_supervisor_command_t.h"
#include "portobello_supervisor_t.h"

#define MAX_SETS 64

typedef struct {
    sv_command_t *cmd;
    sv_proc_t p;
    int out_fd;                 /* read end of the command's stdout+stderr pipe; -1 */
    int log_fd;                 /* NAME.log; -1 */
    int64_t log_bytes;
    char log_path[SV_PATH_MAX * 2 + 80];
    int leader_gone;            /* the process exited; waiting for the rest of its group */
    int exit_code;
    int64_t group_kill_at;      /* SIGKILL what is left of the group at this time; 0 none */
    int64_t cpu_ticks, cpu_at;  /* for cpu_percent */
    float cpu_percent;
    int64_t rss_bytes;
    sv_state_t published_state;
    int32_t published_pid;
} cmd_t;

typedef struct {
    sv_stack_t stack;
    cmd_t *cmds;
    int ncmds;
    int gate[16];               /* group g may start (latched once open) */
    pb_bus_t *bus;
    pb_status_t *status;
    char url[SV_PATH_MAX];
    int64_t next_publish, next_stats;
    int shutting_down;
    const char *sets[MAX_SETS];
    int nsets;
} app_t;

static volatile sig_atomic_t g_signals;
static int g_wake[2] = { -1, -1 };
static volatile pid_t g_pgids[256];
static int g_npgids;

/* First SIGINT/SIGTERM: stop every command in reverse start order, then exit. A second
 * one: SIGKILL every command's process group and exit at once. */
static void on_stop_signal(int sig)
{
    (void)sig;
    if (++g_signals > 1) {
        for (int i = 0; i < g_npgids; i++)
            if (g_pgids[i] > 0) kill(-g_pgids[i], SIGKILL);
        _exit(130);
    }
    int e = errno;
    if (write(g_wake[1], "s", 1) < 0) { /* the pipe is full: we are awake anyway */ }
    errno = e;
}

static void on_sigchld(int sig)
{
    (void)sig;
    int e = errno;
    if (write(g_wake[1], "c", 1) < 0) { /* full: a wake-up is pending */ }
    errno = e;
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: supervisor --config STACK.yaml [--set NAME=VALUE ...] [--lcm-url URL] [--check]\n"
            "Starts the commands of a stack file group by group (a group starts when every command\n"
            "before it is ready: its first STATUS heartbeat, or started), captures and rotates each\n"
            "command's output (OUTPUT_DIR/NAME.log), restarts a command that exits or hangs (no STATUS\n"
            "for heartbeat_s after start_grace_s) with doubling delays, marks it FAILED after\n"
            "max_failures short runs in a row, and publishes every command's state (pid, state,\n"
            "restarts, last exit, CPU, memory) on SUPERVISOR once a second and on every change.\n"
            "SIGINT/SIGTERM stop the commands in reverse order (SIGTERM to each process group, SIGKILL\n"
            "after stop_timeout_s), then the supervisor exits; a second signal kills them at once.\n"
            "Operate it with supervisorctl (list, start, stop, restart, tail). See docs/supervisor.md.\n"
            "  --config FILE     the stack file (stacks/*.yaml)\n"
            "  --set NAME=VALUE  a value for ${NAME} in the stack file (before the environment)\n"
            "  --lcm-url URL     bus for SUPERVISOR/STATUS and for the commands (LCM_DEFAULT_URL is\n"
            "                    set for them): default $LCM_DEFAULT_URL, else the stack's lcm_url,\n"
            "                    else %s\n"
            "  --check           read the stack file, check that every program exists, print the\n"
            "                    start order, and exit (0 = ready)\n"
            "  -h, --help        this text\n",
            PB_DEFAULT_LCM_URL);
}

static const char *lookup(const char *name, void *user)
{
    app_t *a = user;
    size_t n = strlen(name);
    for (int i = a->nsets - 1; i >= 0; i--)
        if (!strncmp(a->sets[i], name, n) && a->sets[i][n] == '=') return a->sets[i] + n + 1;
    return getenv(name);
}

/* ---------------------------------------------------------------- output files */

static void open_log(app_t *a, cmd_t *c)
{
    c->log_fd = open(c->log_path, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (c->log_fd < 0) {
        pb_status_error(a->status, "%s: %s (output of %s is dropped)", c->log_path, strerror(errno), c->cmd->name);
        return;
    }
    struct stat st;
    c->log_bytes = fstat(c->log_fd, &st) == 0 ? st.st_size : 0;
}

/* NAME.log -> NAME.log.1 -> ... -> NAME.log.KEEP (the oldest is dropped). */
static void rotate_log(app_t *a, cmd_t *c)
{
    if (c->log_fd >= 0) close(c->log_fd);
    char from[sizeof c->log_path + 24], to[sizeof c->log_path + 24];
    long keep = a->stack.output_keep;
    if (keep == 0) unlink(c->log_path);
    for (long k = keep - 1; k >= 1; k--) {
        snprintf(from, sizeof from, "%s.%ld", c->log_path, k);
        snprintf(to, sizeof to, "%s.%ld", c->log_path, k + 1);
        rename(from, to);
    }
    if (keep > 0) {
        snprintf(to, sizeof to, "%s.1", c->log_path);
        rename(c->log_path, to);
    }
    open_log(a, c);
}

static void write_log(app_t *a, cmd_t *c, const char *buf, size_t n)
{
    if (c->log_fd < 0) return;
    while (n > 0) {
        ssize_t w = write(c->log_fd, buf, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            pb_status_count(a->status, "output_write_failed", 1);
            pb_status_error(a->status, "%s: %s", c->log_path, strerror(errno));
            return;
        }
        buf += w;
        n -= (size_t)w;
        c->log_bytes += w;
    }
    if (c->log_bytes >= a->stack.output_max_bytes) rotate_log(a, c);
}

static void log_note(app_t *a, cmd_t *c, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void log_note(app_t *a, cmd_t *c, const char *fmt, ...)
{
    char line[1200];
    time_t t = time(NULL);
    struct tm tm;
    gmtime_r(&t, &tm);
    int n = (int)strftime(line, sizeof line, "--- supervisor %Y-%m-%dT%H:%M:%SZ: ", &tm);
    va_list ap;
    va_start(ap, fmt);
    n += vsnprintf(line + n, sizeof line - n - 2, fmt, ap);
    va_end(ap);
    if (n > (int)sizeof line - 2) n = (int)sizeof line - 2;
    line[n++] = '\n';
    write_log(a, c, line, (size_t)n);
}

static void drain_output(app_t *a, cmd_t *c)
{
    char buf[65536];
    for (;;) {
        ssize_t n = read(c->out_fd, buf, sizeof buf);
        if (n > 0) { write_log(a, c, buf, (size_t)n); continue; }
        if (n < 0 && (errno == EINTR)) continue;
        if (n < 0 && errno == EAGAIN) return;
        close(c->out_fd);     /* EOF: every writer (the whole group) has gone */
        c->out_fd = -1;
        return;
    }
}

/* ---------------------------------------------------------------- processes */

static void remember_pgid(pid_t pgid)
{
    for (int i = 0; i < g_npgids; i++)
        if (g_pgids[i] == 0) { g_pgids[i] = pgid; return; }
    if (g_npgids < 256) g_pgids[g_npgids++] = pgid;
}

static void forget_pgid(pid_t pgid)
{
    for (int i = 0; i < g_npgids; i++)
        if (g_pgids[i] == pgid) g_pgids[i] = 0;
}

/* fork + exec in a new process group; stdout and stderr into a pipe; an exec failure
 * comes back through a close-on-exec pipe so it is reported, not counted as a crash. */
static pid_t spawn(app_t *a, cmd_t *c, char *why, size_t whylen)
{
    int out[2], errp[2];
    if (c->out_fd >= 0) { drain_output(a, c); if (c->out_fd >= 0) { close(c->out_fd); c->out_fd = -1; } }
    if (pipe2(out, O_CLOEXEC) != 0) { snprintf(why, whylen, "pipe: %s", strerror(errno)); return -1; }
    if (pipe2(errp, O_CLOEXEC) != 0) { close(out[0]); close(out[1]); snprintf(why, whylen, "pipe: %s", strerror(errno)); return -1; }
    pid_t pid = fork();
    if (pid < 0) {
        snprintf(why, whylen, "fork: %s", strerror(errno));
        close(out[0]); close(out[1]); close(errp[0]); close(errp[1]);
        return -1;
    }
    if (pid == 0) {
        setpgid(0, 0);
        prctl(PR_SET_PDEATHSIG, SIGTERM);       /* the supervisor died: do not linger */
        sigset_t none;
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, NULL);
        signal(SIGINT, SIG_DFL); signal(SIGTERM, SIG_DFL); signal(SIGCHLD, SIG_DFL); signal(SIGPIPE, SIG_DFL);
        int nul = open("/dev/null", O_RDONLY);
        if (nul >= 0) dup2(nul, 0);
        dup2(out[1], 1);
        dup2(out[1], 2);
        int e = 0;
        if (chdir(a->stack.workdir) != 0) e = errno;
        else {
            setenv("LCM_DEFAULT_URL", a->url, 1);
            setenv("PB_SUPERVISOR_STACK", a->stack.name, 1);
            for (int i = 0; i < c->cmd->nenv; i++) putenv(c->cmd->env[i]);
            if (c->cmd->policy.nice > 0 && setpriority(PRIO_PROCESS, 0, (int)c->cmd->policy.nice) != 0) {
                e = errno;
                if (write(errp[1], &e, sizeof e) < 0) { /* the parent sees EOF and reports it */ }
                _exit(127);
            }
            execvp(c->cmd->argv[0], c->cmd->argv);
            e = errno;
        }
        if (write(errp[1], &e, sizeof e) < 0) { /* the parent sees EOF and reports it */ }
        _exit(127);
    }
    setpgid(pid, pid);
    close(out[1]);
    close(errp[1]);
    int e = 0;
    ssize_t n;
    do n = read(errp[0], &e, sizeof e); while (n < 0 && errno == EINTR);
    close(errp[0]);
    if (n == (ssize_t)sizeof e) {
        snprintf(why, whylen, "%s: %s (in %s)", c->cmd->argv[0], strerror(e), a->stack.workdir);
        waitpid(pid, NULL, 0);
        close(out[0]);
        return -1;
    }
    fcntl(out[0], F_SETFL, O_NONBLOCK);
    c->out_fd = out[0];
    remember_pgid(pid);
    return pid;
}

static void signal_group(cmd_t *c, int sig)
{
    pid_t pg = c->p.pid;
    if (pg <= 0) return;
    if (sig == SIGTERM) kill(-pg, SIGCONT);     /* a stopped process must run to see SIGTERM */
    kill(-pg, sig);
    if (sig == SIGTERM) kill(-pg, SIGCONT);
}

static int group_alive(pid_t pg) { return pg > 0 && (kill(-pg, 0) == 0 || errno == EPERM); }

static cmd_t *by_pid(app_t *a, pid_t pid)
{
    for (int i = 0; i < a->ncmds; i++)
        if (a->cmds[i].p.pid == pid) return &a->cmds[i];
    return NULL;
}

/* Collects exit statuses (also of orphans in our groups: we are their subreaper). */
static void reap(app_t *a, int64_t now)
{
    int st;
    pid_t pid;
    while ((pid = waitpid(-1, &st, WNOHANG)) > 0) {
        cmd_t *c = by_pid(a, pid);
        if (!c || c->leader_gone) continue;
        c->leader_gone = 1;
        c->exit_code = WIFEXITED(st) ? WEXITSTATUS(st) : WIFSIGNALED(st) ? -WTERMSIG(st) : -1;
        if (c->p.state != SV_STOPPING && group_alive(pid)) {
            /* The leader died but others of its group live (a wrapper's child): stop them. */
            kill(-pid, SIGTERM);
            c->group_kill_at = now + (int64_t)(c->cmd->policy.stop_timeout_s * 1e6);
        }
    }
    /* A command has exited once its whole process group has. */
    for (int i = 0; i < a->ncmds; i++) {
        cmd_t *c = &a->cmds[i];
        if (!c->leader_gone) continue;
        pid_t pg = c->p.pid;
        if (group_alive(pg)) {
            if (c->group_kill_at && now >= c->group_kill_at) { kill(-pg, SIGKILL); c->group_kill_at = 0; }
            continue;
        }
        if (c->out_fd >= 0) drain_output(a, c);
        if (c->exit_code >= 0) log_note(a, c, "pid %d exited with status %d", (int)pg, c->exit_code);
        else log_note(a, c, "pid %d killed by signal %d (%s)", (int)pg, -c->exit_code, strsignal(-c->exit_code));
        forget_pgid(pg);
        c->leader_gone = 0;
        c->group_kill_at = 0;
        sv_proc_exited(&c->p, c->exit_code, now);
        c->cpu_percent = 0;
        c->rss_bytes = 0;
    }
}

/* ---------------------------------------------------------------- /proc figures */

/* CPU ticks and resident bytes of every process in each command's process group. */
static void update_stats(app_t *a, int64_t now)
{
    int64_t ticks[a->ncmds], rss[a->ncmds];
    memset(ticks, 0, sizeof ticks);
    memset(rss, 0, sizeof rss);
    long page = sysconf(_SC_PAGESIZE), hz = sysconf(_SC_CLK_TCK);
    DIR *d = opendir("/proc");
    if (!d) return;
    struct dirent *de;
    while ((de = readdir(d))) {
        if (de->d_name[0] < '0' || de->d_name[0] > '9') continue;
        char path[300], buf[1024];
        snprintf(path, sizeof path, "/proc/%s/stat", de->d_name);
        int fd = open(path, O_RDONLY);
        if (fd < 0) continue;
        ssize_t n = read(fd, buf, sizeof buf - 1);
        close(fd);
        if (n <= 0) continue;
        buf[n] = 0;
        char *p = strrchr(buf, ')');     /* the command name may hold spaces */
        if (!p) continue;
        /* after ')': state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt utime stime
         * cutime cstime priority nice threads itrealvalue starttime vsize rss */
        char state;
        int ppid, pgrp;
        unsigned long long ut, stt, vsize;
        long long rsspages;
        if (sscanf(p + 1, " %c %d %d %*d %*d %*d %*u %*u %*u %*u %*u %llu %llu %*d %*d %*d %*d %*d %*d %*u %llu %lld",
                   &state, &ppid, &pgrp, &ut, &stt, &vsize, &rsspages) != 7)
            continue;
        for (int i = 0; i < a->ncmds; i++)
            if (a->cmds[i].p.pid > 0 && a->cmds[i].p.pid == pgrp) {
                ticks[i] += (int64_t)(ut + stt);
                rss[i] += rsspages * page;
            }
    }
    closedir(d);
    for (int i = 0; i < a->ncmds; i++) {
        cmd_t *c = &a->cmds[i];
        if (c->p.pid <= 0) { c->cpu_percent = 0; c->rss_bytes = 0; c->cpu_at = 0; continue; }
        if (c->cpu_at && ticks[i] >= c->cpu_ticks && now > c->cpu_at)
            c->cpu_percent = (float)((ticks[i] - c->cpu_ticks) * 100.0 / hz / ((now - c->cpu_at) * 1e-6));
        c->cpu_ticks = ticks[i];
        c->cpu_at = now;
        c->rss_bytes = rss[i];
    }
}

/* ---------------------------------------------------------------- LCM */

static void publish_state(app_t *a, int64_t now)
{
    portobello_command_state_t cs[a->ncmds];
    for (int i = 0; i < a->ncmds; i++) {
        cmd_t *c = &a->cmds[i];
        cs[i] = (portobello_command_state_t){
            .name = c->cmd->name, .group = c->cmd->group, .state = (int8_t)c->p.state, .pid = c->p.pid,
            .restarts = c->p.restarts, .quick_failures = c->p.failures, .last_exit = c->p.last_exit,
            .last_exit_utime = c->p.last_exit_us ? pb_bus_now(a->bus) - (now - c->p.last_exit_us) : 0,
            .uptime_s = c->p.pid > 0 ? (float)((now - c->p.started_us) * 1e-6) : 0,
            .cpu_percent = c->cpu_percent, .rss_bytes = c->p.pid > 0 ? c->rss_bytes : 0,
            .heartbeat_age_s = c->p.pid > 0 && c->p.last_status_us ? (float)((now - c->p.last_status_us) * 1e-6) : -1,
            .module_state = (int8_t)c->p.module_state, .output_path = c->log_path, .detail = c->p.detail,
        };
        c->published_state = c->p.state;
        c->published_pid = c->p.pid;
    }
    char cfg_path[SV_PATH_MAX];
    snprintf(cfg_path, sizeof cfg_path, "%s", a->stack.path);
    portobello_supervisor_t m = { .utime = pb_bus_now(a->bus), .stack = a->stack.name, .config_path = cfg_path,
                                  .pid = (int32_t)getpid(), .ncommands = a->ncmds, .commands = cs };
    pb_err_t err;
    if (PB_PUBLISH(a->bus, "SUPERVISOR", portobello_supervisor_t, &m, &err)) pb_status_error(a->status, "SUPERVISOR: %s", err.msg);
    a->next_publish = now + 1000000;
}

static pid_t pgid_of(pid_t pid)
{
    pid_t g = getpgid(pid);
    return g < 0 ? 0 : g;
}

/* A STATUS belongs to the command whose process group holds its pid. */
static void on_status(const pb_msg_t *m, void *user)
{
    app_t *a = user;
    portobello_status_t s;
    if (portobello_status_t_decode(m->data, 0, m->len, &s) < 0) {
        pb_status_count(a->status, "undecodable_status", 1);
        return;
    }
    if (s.pid > 0 && s.pid != getpid()) {
        cmd_t *c = by_pid(a, s.pid);
        if (!c) {
            pid_t g = pgid_of(s.pid);
            if (g > 0) c = by_pid(a, g);
        }
        if (c && !c->leader_gone) {
            int was = c->p.state;
            sv_proc_heartbeat(&c->p, pb_bus_monotonic(a->bus), s.state);
            if (was != (int)c->p.state) log_note(a, c, "pid %d ready (STATUS from its running loop: %s)", (int)c->p.pid, s.module);
        }
    }
    portobello_status_t_decode_cleanup(&s);
}

static int apply(app_t *a, const char *action, const char *target)
{
    int64_t now = pb_bus_monotonic(a->bus);
    int g = sv_stack_find_group(&a->stack, target), n = 0;
    for (int i = 0; i < a->ncmds; i++) {
        cmd_t *c = &a->cmds[i];
        if (strcmp(target, "all") && strcmp(target, c->cmd->name) && (g < 0 || c->cmd->group_index != g)) continue;
        if (!strcmp(action, "start")) sv_proc_start(&c->p, now);
        else if (!strcmp(action, "stop")) sv_proc_stop(&c->p, now);
        else if (!strcmp(action, "restart")) sv_proc_restart(&c->p, now);
        else return -1;
        n++;
    }
    /* Starting on request does not wait for earlier groups. */
    if (!strcmp(action, "stop")) return n;
    for (int k = 0; k < a->stack.ngroups; k++) a->gate[k] = 1;
    return n;
}

static void on_command(const pb_msg_t *m, void *user)
{
    app_t *a = user;
    portobello_supervisor_command_t cmd;
    if (portobello_supervisor_command_t_decode(m->data, 0, m->len, &cmd) < 0) {
        pb_status_count(a->status, "undecodable_command", 1);
        return;
    }
    if (!cmd.stack[0] || !strcmp(cmd.stack, a->stack.name)) {
        int n = a->shutting_down ? 0 : apply(a, cmd.action, cmd.target);
        if (n < 0) pb_status_error(a->status, "SUPERVISOR_COMMAND: unknown action '%s'", cmd.action);
        else if (n == 0) pb_status_error(a->status, "SUPERVISOR_COMMAND: %s %s: no such command or group", cmd.action, cmd.target);
        else fprintf(stderr, "supervisor: %s %s\n", cmd.action, cmd.target);
        pb_status_count(a->status, "commands", 1);
    }
    portobello_supervisor_command_t_decode_cleanup(&cmd);
}

/* ---------------------------------------------------------------- the loop */

static void act(app_t *a, cmd_t *c, sv_action_t what, int64_t now)
{
    char why[1500];
    switch (what) {
    case SV_DO_START: {
        pid_t pid = spawn(a, c, why, sizeof why);
        if (pid < 0) {
            sv_proc_start_failed(&c->p, now, why);
            log_note(a, c, "cannot start: %s", why);
            fprintf(stderr, "supervisor: %s: cannot start: %s\n", c->cmd->name, why);
            return;
        }
        sv_proc_started(&c->p, pid, now);
        log_note(a, c, "started pid %d (run %d)", (int)pid, c->p.runs);
        return;
    }
    case SV_DO_TERM:
        log_note(a, c, "stopping pid %d: %s", (int)c->p.pid, c->p.detail);
        if (strncmp(c->p.detail, "hang", 4) == 0) fprintf(stderr, "supervisor: %s: %s\n", c->cmd->name, c->p.detail);
        signal_group(c, SIGTERM);
        return;
    case SV_DO_KILL:
        log_note(a, c, "pid %d still running %.1f s after SIGTERM: SIGKILL to its process group", (int)c->p.pid,
                 c->cmd->policy.stop_timeout_s);
        signal_group(c, SIGKILL);
        return;
    default:
        return;
    }
}

/* Stops the highest group that still runs; returns 1 once nothing runs. */
static int shutdown_step(app_t *a, int64_t now)
{
    for (int g = a->stack.ngroups - 1; g >= 0; g--) {
        int live = 0;
        for (int i = 0; i < a->ncmds; i++) {
            cmd_t *c = &a->cmds[i];
            if (c->cmd->group_index != g) continue;
            if (c->p.wanted || c->p.state == SV_STARTING || c->p.state == SV_RUNNING) sv_proc_stop(&c->p, now);
            if (c->p.pid > 0 || c->leader_gone) live = 1;
        }
        if (live) return 0;
    }
    return 1;
}

static int turn(app_t *a)
{
    int64_t now = pb_bus_monotonic(a->bus);
    reap(a, now);
    if (g_signals && !a->shutting_down) {
        a->shutting_down = 1;
        fprintf(stderr, "supervisor: stopping every command (reverse start order)\n");
    }
    if (a->shutting_down && shutdown_step(a, now)) return 1;
    /* Group gates: open once every command of the groups before is ready. */
    for (int g = 0; g < a->stack.ngroups; g++) {
        if (a->gate[g]) continue;
        int open = 1;
        for (int i = 0; i < a->ncmds; i++)
            if (a->cmds[i].cmd->group_index < g && a->cmds[i].p.wanted && !sv_proc_ready(&a->cmds[i].p)) open = 0;
        a->gate[g] = open;
        if (!open) break;
    }
    for (int i = 0; i < a->ncmds; i++) {
        cmd_t *c = &a->cmds[i];
        if (c->leader_gone) {
            /* Exited leader, group still alive: its stop deadline still applies. */
            if (c->p.state == SV_STOPPING && !c->p.killed && now >= c->p.stop_deadline_us) {
                c->p.killed = 1;
                kill(-c->p.pid, SIGKILL);
            }
            continue;
        }
        act(a, c, sv_proc_tick(&c->p, now, a->gate[c->cmd->group_index] && !a->shutting_down), now);
    }
    if (now >= a->next_stats) {
        update_stats(a, now);
        a->next_stats = now + 1000000;
    }
    int changed = 0;
    for (int i = 0; i < a->ncmds; i++)
        if (a->cmds[i].p.state != a->cmds[i].published_state || a->cmds[i].p.pid != a->cmds[i].published_pid) changed = 1;
    if (changed || now >= a->next_publish) publish_state(a, now);
    return 0;
}

static int run(app_t *a)
{
    pb_err_t err;
    for (;;) {
        if (turn(a)) return 0;
        struct pollfd fds[2 + a->ncmds];
        cmd_t *who[2 + a->ncmds];
        int n = 0;
        fds[n] = (struct pollfd){ .fd = pb_bus_fileno(a->bus), .events = POLLIN }; who[n++] = NULL;
        fds[n] = (struct pollfd){ .fd = g_wake[0], .events = POLLIN }; who[n++] = NULL;
        for (int i = 0; i < a->ncmds; i++)
            if (a->cmds[i].out_fd >= 0) { fds[n] = (struct pollfd){ .fd = a->cmds[i].out_fd, .events = POLLIN }; who[n++] = &a->cmds[i]; }
        /* 20 ms: restarts, stop deadlines and heartbeat verdicts are checked this often. */
        int r = poll(fds, (nfds_t)n, 20);
        if (r < 0 && errno != EINTR) { fprintf(stderr, "supervisor: poll: %s\n", strerror(errno)); return -1; }
        if (r > 0 && (fds[1].revents & POLLIN)) {
            char junk[256];
            while (read(g_wake[0], junk, sizeof junk) > 0) {}
        }
        for (int i = 2; i < n; i++)
            if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) drain_output(a, who[i]);
        if (pb_bus_dispatch(a->bus, &err)) { fprintf(stderr, "supervisor: %s\n", err.msg); return -1; }
    }
}

/* --check: every program must exist and be executable from workdir (or PATH). */
static int check_programs(app_t *a)
{
    int bad = 0;
    for (int i = 0; i < a->ncmds; i++) {
        const char *prog = a->cmds[i].cmd->argv[0];
        char path[SV_PATH_MAX * 2];
        int ok = 0;
        if (strchr(prog, '/')) {
            if (prog[0] == '/') snprintf(path, sizeof path, "%s", prog);
            else snprintf(path, sizeof path, "%s/%s", a->stack.workdir, prog);
            ok = access(path, X_OK) == 0;
        } else {
            const char *pathenv = getenv("PATH");
            char dirs[4096];
            snprintf(dirs, sizeof dirs, "%s", pathenv ? pathenv : "/usr/bin:/bin");
            for (char *save, *d = strtok_r(dirs, ":", &save); d && !ok; d = strtok_r(NULL, ":", &save)) {
                snprintf(path, sizeof path, "%s/%s", d, prog);
                ok = access(path, X_OK) == 0;
            }
        }
        if (!ok) {
            fprintf(stderr, "supervisor: %s:%d: %s: program '%s' not found or not executable (in %s)\n", a->stack.path,
                    a->cmds[i].cmd->line, a->cmds[i].cmd->name, prog, a->stack.workdir);
            bad = 1;
        }
    }
    return bad;
}

static int mkdirs(const char *path)
{
    char tmp[SV_PATH_MAX * 2];
    snprintf(tmp, sizeof tmp, "%s", path);
    for (char *p = tmp + 1; *p; p++)
        if (*p == '/') { *p = 0; mkdir(tmp, 0755); *p = '/'; }
    return mkdir(tmp, 0755) == 0 || errno == EEXIST ? 0 : -1;
}

/* --set NAME=VALUE, repeatable. */
static int add_set(const char *prog, const char *arg, void *var)
{
    app_t *a = var;
    if (!strchr(arg, '=') || arg[0] == '=' || a->nsets >= MAX_SETS) {
        fprintf(stderr, "%s: --set: expected NAME=VALUE, got '%s'\n", prog, arg);
        return -1;
    }
    a->sets[a->nsets++] = arg;
    return 0;
}

int main(int argc, char **argv)
{
    static app_t a;
    const char *config = NULL, *cli_url = NULL;
    int check_only = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("config", &config), PB_OPT_CALL("set", add_set, &a), PB_OPT_STRING("lcm-url", &cli_url),
        PB_OPT_FLAG("check", &check_only, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("supervisor", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;

    pb_err_t err;
    if (sv_stack_load(config, lookup, &a, &a.stack, &err)) { fprintf(stderr, "supervisor: %s\n", err.msg); return 1; }
    const char *env_url = getenv("LCM_DEFAULT_URL");
    snprintf(a.url, sizeof a.url, "%s", cli_url && *cli_url ? cli_url : env_url && *env_url ? env_url
                                        : a.stack.lcm_url[0] ? a.stack.lcm_url : PB_DEFAULT_LCM_URL);
    a.ncmds = a.stack.ncommands;
    a.cmds = calloc(a.ncmds, sizeof *a.cmds);
    char outdir[SV_PATH_MAX * 2];
    if (a.stack.output_dir[0] == '/') snprintf(outdir, sizeof outdir, "%s", a.stack.output_dir);
    else snprintf(outdir, sizeof outdir, "%s/%s", a.stack.workdir, a.stack.output_dir);
    for (int i = 0; i < a.ncmds; i++) {
        cmd_t *k = &a.cmds[i];
        k->cmd = &a.stack.commands[i];
        sv_proc_init(&k->p, &k->cmd->policy);
        k->out_fd = k->log_fd = -1;
        k->published_state = (sv_state_t)-1;
        snprintf(k->log_path, sizeof k->log_path, "%s/%s.log", outdir, k->cmd->name);
    }
    if (check_only) {
        int bad = check_programs(&a);
        printf("%s: stack %s, %d commands in %d groups, run in %s, output in %s, bus %s\n", config, a.stack.name, a.ncmds,
               a.stack.ngroups, a.stack.workdir, outdir, a.url);
        for (int g = 0; g < a.stack.ngroups; g++) {
            printf("  %d. %s:", g + 1, a.stack.groups[g]);
            for (int i = 0; i < a.ncmds; i++)
                if (a.cmds[i].cmd->group_index == g) printf(" %s", a.cmds[i].cmd->name);
            printf("\n");
        }
        sv_stack_free(&a.stack);
        return bad ? 1 : 0;
    }
    if (mkdirs(outdir)) { fprintf(stderr, "supervisor: %s: %s\n", outdir, strerror(errno)); return 1; }

    a.bus = pb_bus_create_live(a.url, &err);
    if (!a.bus) { fprintf(stderr, "supervisor: %s\n", err.msg); return 1; }
    a.status = pb_status_create(a.bus, "supervisor", 1000000);
    pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_OK);
    pb_bus_subscribe(a.bus, "STATUS", on_status, &a);
    pb_bus_subscribe(a.bus, "SUPERVISOR_COMMAND", on_command, &a);
    for (int i = 0; i < a.ncmds; i++) open_log(&a, &a.cmds[i]);

    /* Signals: a self-pipe wakes poll(); orphans of our commands' groups become our
     * children (subreaper) so they are reaped and counted in their group. */
    if (pipe2(g_wake, O_CLOEXEC | O_NONBLOCK) != 0) { perror("supervisor: pipe"); return 1; }
    prctl(PR_SET_CHILD_SUBREAPER, 1);
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sigemptyset(&sa.sa_mask);
    sa.sa_handler = on_stop_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sa.sa_handler = on_sigchld;
    sa.sa_flags = SA_NOCLDSTOP | SA_RESTART;
    sigaction(SIGCHLD, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    fprintf(stderr, "supervisor: stack %s (%s): %d commands in %d groups, bus %s, output in %s\n", a.stack.name, config,
            a.ncmds, a.stack.ngroups, a.url, outdir);
    int64_t now = pb_bus_monotonic(a.bus);
    for (int i = 0; i < a.ncmds; i++) sv_proc_start(&a.cmds[i].p, now);
    a.gate[0] = 1;
    int rc = run(&a);
    publish_state(&a, pb_bus_monotonic(a.bus));
    pb_status_finish(a.status, NULL);
    for (int i = 0; i < a.ncmds; i++) if (a.cmds[i].log_fd >= 0) close(a.cmds[i].log_fd);
    fprintf(stderr, "supervisor: every command stopped\n");
    pb_status_destroy(a.status);
    pb_bus_destroy(a.bus);
    sv_stack_free(&a.stack);
    free(a.cmds);
    return rc == 0 ? 0 : 1;
}
