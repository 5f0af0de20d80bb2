/* supervisorctl: operates a running supervisor over LCM.
 *   supervisorctl [--stack NAME] list | start T | stop T | restart T | tail NAME [-n N] [-f]
 * Reads SUPERVISOR (the state of every command), sends SUPERVISOR_COMMAND and waits
 * until the state shows the request was carried out. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "pb_arg.h"
#include "pb_bus.h"
#include "pb_opt.h"
#include "portobello_supervisor_command_t.h"
#include "portobello_supervisor_t.h"

typedef struct {
    const char *stack;          /* --stack, or the first supervisor heard */
    portobello_supervisor_t last;
    int have, fresh;
    char other_stack[64];
} ctl_t;

static const char *state_name(int s)
{
    static const char *names[] = { "STOPPED", "WAITING", "STARTING", "RUNNING", "BACKOFF", "STOPPING", "EXITED", "FAILED" };
    return s >= 0 && s < 8 ? names[s] : "UNKNOWN";
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: supervisorctl [--stack NAME] [--lcm-url URL] [--timeout S] COMMAND\n"
            "Operates the supervisor of a stack over LCM (docs/supervisor.md).\n"
            "  list                 every command: state, pid, uptime, restarts, last exit, CPU, memory,\n"
            "                       heartbeat age, and why it is in that state\n"
            "  start TARGET         start a command, a group, or all (also recovers FAILED)\n"
            "  stop TARGET          stop it (SIGTERM to its process group, SIGKILL after its timeout)\n"
            "  restart TARGET       stop and start again\n"
            "  tail NAME [-n N] [-f]  the last N lines (default 20) of its output; -f follows it\n"
            "  --stack NAME         the supervisor of this stack (default: the first one heard)\n"
            "  --lcm-url URL        bus (default $LCM_DEFAULT_URL or %s)\n"
            "  --timeout S          how long to wait for the supervisor and for the request to be\n"
            "                       carried out (default 30)\n"
            "  -h, --help           this text\n"
            "Exit status: 0 done, 1 not done in time or no supervisor heard, 2 bad usage.\n",
            PB_DEFAULT_LCM_URL);
}

static void on_supervisor(const pb_msg_t *m, void *user)
{
    ctl_t *c = user;
    portobello_supervisor_t s;
    if (portobello_supervisor_t_decode(m->data, 0, m->len, &s) < 0) return;
    if (c->stack && strcmp(c->stack, s.stack)) {
        snprintf(c->other_stack, sizeof c->other_stack, "%s", s.stack);
        portobello_supervisor_t_decode_cleanup(&s);
        return;
    }
    if (c->have) portobello_supervisor_t_decode_cleanup(&c->last);
    else if (!c->stack) c->stack = strdup(s.stack);
    c->last = s;
    c->have = 1;
    c->fresh = 1;
}

/* Waits for the next SUPERVISOR message, up to the deadline; 0 or -1. */
static int wait_state(pb_bus_t *bus, ctl_t *c, int64_t deadline)
{
    c->fresh = 0;
    pb_err_t err;
    while (!c->fresh) {
        int64_t left = deadline - pb_bus_monotonic(bus);
        if (left <= 0) return -1;
        struct pollfd p = { .fd = pb_bus_fileno(bus), .events = POLLIN };
        poll(&p, 1, (int)(left / 1000 + 1) > 100 ? 100 : (int)(left / 1000 + 1));
        if (pb_bus_dispatch(bus, &err)) { fprintf(stderr, "supervisorctl: %s\n", err.msg); return -1; }
    }
    return 0;
}

static int matches(const portobello_command_state_t *cs, const char *target)
{
    return !strcmp(target, "all") || !strcmp(target, cs->name) || !strcmp(target, cs->group);
}

static void print_table(const portobello_supervisor_t *s, const char *target)
{
    printf("stack %s (%s), supervisor pid %d\n", s->stack, s->config_path, s->pid);
    printf("%-14s %-10s %-9s %7s %8s %4s %9s %6s %9s %6s  %s\n", "NAME", "GROUP", "STATE", "PID", "UPTIME", "RST",
           "LAST-EXIT", "CPU%", "RSS-MB", "HB-S", "DETAIL");
    for (int i = 0; i < s->ncommands; i++) {
        const portobello_command_state_t *cs = &s->commands[i];
        if (target && !matches(cs, target)) continue;
        char ex[16] = "-", hb[16] = "-", rss[16] = "-";
        if (cs->last_exit != PORTOBELLO_COMMAND_STATE_T_EXIT_NONE) {
            if (cs->last_exit >= 0) snprintf(ex, sizeof ex, "%d", cs->last_exit);
            else snprintf(ex, sizeof ex, "sig %d", -cs->last_exit);
        }
        if (cs->heartbeat_age_s >= 0) snprintf(hb, sizeof hb, "%.1f", cs->heartbeat_age_s);
        if (cs->pid > 0 && cs->rss_bytes >= 0) snprintf(rss, sizeof rss, "%.1f", cs->rss_bytes / 1048576.0);
        printf("%-14s %-10s %-9s %7d %8.1f %4d %9s %6.1f %9s %6s  %s\n", cs->name, cs->group, state_name(cs->state), cs->pid,
               cs->uptime_s, cs->restarts, ex, cs->cpu_percent, rss, hb, cs->detail);
    }
}

/* Is the request carried out for every command it names? */
static int done(const portobello_supervisor_t *s, const char *action, const char *target, const int32_t *old_pid,
                const int32_t *old_restarts)
{
    int any = 0;
    for (int i = 0; i < s->ncommands; i++) {
        const portobello_command_state_t *cs = &s->commands[i];
        if (!matches(cs, target)) continue;
        any = 1;
        int st = cs->state;
        if (!strcmp(action, "stop") && st != PORTOBELLO_COMMAND_STATE_T_STATE_STOPPED &&
            st != PORTOBELLO_COMMAND_STATE_T_STATE_EXITED && st != PORTOBELLO_COMMAND_STATE_T_STATE_FAILED)
            return 0;
        if (strcmp(action, "stop") && st != PORTOBELLO_COMMAND_STATE_T_STATE_RUNNING &&
            !(st == PORTOBELLO_COMMAND_STATE_T_STATE_EXITED && cs->last_exit == 0))
            return 0;
        if (!strcmp(action, "restart") && i < 256 && cs->pid == old_pid[i] && cs->restarts == old_restarts[i]) return 0;
    }
    return any;
}

/* The last n lines of a file, then (follow) what is appended, across rotations. */
static int tail_file(const char *path, int n, int follow)
{
    FILE *f = fopen(path, "r");
    if (!f) { fprintf(stderr, "supervisorctl: %s: %s\n", path, strerror(errno)); return 1; }
    fseek(f, 0, SEEK_END);
    long end = ftell(f), pos = end, start = n == 0 ? end : 0;
    int lines = 0;
    /* Walk back to just after the n-th newline from the end (a final newline aside). */
    while (n > 0 && pos > 0) {
        long step = pos > 4096 ? 4096 : pos;
        char buf[4096];
        pos -= step;
        fseek(f, pos, SEEK_SET);
        if (fread(buf, 1, (size_t)step, f) != (size_t)step) break;
        for (long i = step - 1; i >= 0; i--)
            if (buf[i] == '\n' && pos + i != end - 1 && ++lines == n) { start = pos + i + 1; goto found; }
    }
found:
    pos = start;
    fseek(f, pos, SEEK_SET);
    char buf[65536];
    size_t r;
    while ((r = fread(buf, 1, sizeof buf, f)) > 0) fwrite(buf, 1, r, stdout);
    fflush(stdout);
    while (follow) {
        usleep(200000);
        clearerr(f);
        while ((r = fread(buf, 1, sizeof buf, f)) > 0) { fwrite(buf, 1, r, stdout); fflush(stdout); }
        struct stat a, b;
        if (stat(path, &a) == 0 && fstat(fileno(f), &b) == 0 && a.st_ino != b.st_ino) {
            FILE *g = fopen(path, "r");     /* rotated: continue in the new file */
            if (g) { fclose(f); f = g; }
        }
    }
    fclose(f);
    return 0;
}

int main(int argc, char **argv)
{
    const char *url = NULL;
    ctl_t c = { 0 };
    double timeout = 30;
    long nlines = 20;
    int follow = 0;
    const pb_opt_t opts[] = {
        PB_OPT_STRING("stack", &c.stack), PB_OPT_STRING("lcm-url", &url), PB_OPT_DOUBLE("timeout", &timeout, 0.1, 86400),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("supervisorctl", opts, usage, PB_OPT_IN_ORDER, argc, argv);
    if (parsed >= 0) return parsed;
    if (optind >= argc) { usage(stderr); return 2; }
    const char *action = argv[optind++];
    const char *target = NULL;
    if (strcmp(action, "list")) {
        if (optind >= argc) { fprintf(stderr, "supervisorctl: %s needs a command, group or 'all'\n", action); return 2; }
        target = argv[optind++];
    }
    if (!strcmp(action, "tail")) {
        while (optind < argc) {
            if (!strcmp(argv[optind], "-f")) follow = 1;
            else if (!strcmp(argv[optind], "-n") && optind + 1 < argc) {
                if (pb_arg_long("supervisorctl", "-n", argv[++optind], 0, 1000000, &nlines)) return 2;
            } else { fprintf(stderr, "supervisorctl: tail: unexpected '%s'\n", argv[optind]); return 2; }
            optind++;
        }
    }
    if (optind < argc) { fprintf(stderr, "supervisorctl: unexpected argument '%s'\n", argv[optind]); return 2; }
    if (strcmp(action, "list") && strcmp(action, "start") && strcmp(action, "stop") && strcmp(action, "restart") &&
        strcmp(action, "tail")) {
        fprintf(stderr, "supervisorctl: unknown command '%s'\n", action);
        usage(stderr);
        return 2;
    }

    pb_err_t err;
    pb_bus_t *bus = pb_bus_create_live(url, &err);
    if (!bus) { fprintf(stderr, "supervisorctl: %s\n", err.msg); return 1; }
    pb_bus_subscribe(bus, "SUPERVISOR", on_supervisor, &c);
    int64_t deadline = pb_bus_monotonic(bus) + (int64_t)(timeout * 1e6);
    int rc = 1;
    if (wait_state(bus, &c, pb_bus_monotonic(bus) + (int64_t)((timeout < 3 ? timeout : 3) * 1e6))) {
        fprintf(stderr, "supervisorctl: no supervisor%s%s heard on %s%s%s\n", c.stack ? " of stack " : "", c.stack ? c.stack : "",
                pb_lcm_url(url), c.other_stack[0] ? " (heard stack " : "", c.other_stack[0] ? c.other_stack : "");
        if (c.other_stack[0]) fprintf(stderr, ")\n");
        goto out;
    }
    if (!strcmp(action, "list")) { print_table(&c.last, NULL); rc = 0; goto out; }
    int found = 0;
    for (int i = 0; i < c.last.ncommands; i++) found |= matches(&c.last.commands[i], target);
    if (!found) { fprintf(stderr, "supervisorctl: stack %s has no command or group '%s'\n", c.last.stack, target); rc = 2; goto out; }
    if (!strcmp(action, "tail")) {
        for (int i = 0; i < c.last.ncommands; i++)
            if (!strcmp(c.last.commands[i].name, target)) { rc = tail_file(c.last.commands[i].output_path, (int)nlines, follow); goto out; }
        fprintf(stderr, "supervisorctl: tail takes a command name, not a group\n");
        rc = 2;
        goto out;
    }
    int32_t old_pid[256] = { 0 }, old_restarts[256] = { 0 };
    for (int i = 0; i < c.last.ncommands && i < 256; i++) {
        old_pid[i] = c.last.commands[i].pid;
        old_restarts[i] = c.last.commands[i].restarts;
    }
    portobello_supervisor_command_t m = { .utime = 0, .stack = (char *)c.last.stack, .action = (char *)action, .target = (char *)target };
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    m.utime = (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
    if (PB_PUBLISH(bus, "SUPERVISOR_COMMAND", portobello_supervisor_command_t, &m, &err)) {
        fprintf(stderr, "supervisorctl: %s\n", err.msg);
        goto out;
    }
    while (!done(&c.last, action, target, old_pid, old_restarts)) {
        if (wait_state(bus, &c, deadline)) {
            fprintf(stderr, "supervisorctl: %s %s: not done after %.0f s; the state now:\n", action, target, timeout);
            print_table(&c.last, target);
            goto out;
        }
    }
    print_table(&c.last, target);
    rc = 0;
out:
    if (c.have) portobello_supervisor_t_decode_cleanup(&c.last);
    pb_bus_destroy(bus);
    return rc;
}
