/* supervisor core: stack files (strict, with file:line) and the per-command state
 * machine (restarts, doubling backoff reset by a stable run, FAILED and its recovery,
 * hang verdicts after the start-up grace, stop deadlines). */
#include <stdlib.h>
#include <unistd.h>

#include "supervisor/core/proc.h"
#include "supervisor/core/stack.h"
#include "pb_check.h"

static char dir[] = "/tmp/pb_test_supervisor_XXXXXX";

static const char *lookup(const char *name, void *user)
{
    (void)user;
    if (!strcmp(name, "PARTICIPANT")) return "P07";
    if (!strcmp(name, "EMPTY")) return "";
    return NULL;
}

static int load(const char *text, sv_stack_t *s, pb_err_t *err)
{
    return sv_stack_load(pb_check_write_file(dir, "stack.yaml", text), lookup, NULL, s, err);
}

#define S(x) ((int64_t)((x) * 1e6))

static void test_stack(void)
{
    sv_stack_t s;
    pb_err_t err;
    int rc = load("name: road\n"
                  "lcm_url: udpm://239.255.76.67:7990?ttl=0\n"
                  "workdir: ..\n"
                  "defaults: {heartbeat_s: 2, stable_s: 5}\n"
                  "groups:\n"
                  "  - name: rec\n"
                  "    commands:\n"
                  "      - name: logger\n"
                  "        run: [lcm-logger, \"rec/${PARTICIPANT}_${SESSION:-s1}.lcm\"]\n"
                  "        ready: started\n"
                  "        heartbeat_s: 0\n"
                  "  - name: live\n"
                  "    commands:\n"
                  "      - name: director\n"
                  "        run: [build/bin/director, --site, \"${EMPTY:-maps/default}\"]\n"
                  "        env: {A: \"x${PARTICIPANT}\"}\n"
                  "        restart: on-failure\n",
                  &s, &err);
    if (CHECK_OK(rc, err.msg)) return;
    CHECK(s.ncommands == 2 && s.ngroups == 2);
    CHECK(!strcmp(s.commands[0].argv[1], "rec/P07_s1.lcm"));
    CHECK(!strcmp(s.commands[1].argv[2], "maps/default"));
    CHECK(s.commands[1].argv[3] == NULL);
    CHECK(!strcmp(s.commands[1].env[0], "A=xP07"));
    CHECK(s.commands[0].policy.ready == SV_READY_STARTED && s.commands[0].policy.heartbeat_s == 0);
    CHECK(s.commands[1].policy.heartbeat_s == 2 && s.commands[1].policy.stable_s == 5);
    CHECK(s.commands[1].policy.restart == SV_RESTART_ON_FAILURE && s.commands[1].group_index == 1);
    CHECK_CONTAINS(s.workdir, "/..");
    sv_stack_free(&s);

    /* Refusals name file and line. */
    struct { const char *text, *want; } bad[] = {
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x]\n        restrat: always\n", "stack.yaml:7: unknown key 'restrat'" },
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x, \"${NOPE}\"]\n", "stack.yaml:6: unset variable NOPE" },
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x]\n      - name: a\n        run: [y]\n", "stack.yaml:7: command name 'a' is used twice" },
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x]\n        heartbeat_s: \"3\"\n", "stack.yaml:7" },
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: []\n", "stack.yaml:6: a: run: expected a list" },
        { "name: x\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x]\n        restart: sometimes\n", "restart: expected always, on-failure or never, got 'sometimes'" },
        { "name: x\ndefaults: {backoff_initial_s: 5, backoff_max_s: 1}\ngroups:\n  - name: g\n    commands:\n      - name: a\n        run: [x]\n", "backoff_max_s is below" },
        { "name: x\ngroups:\n  - name: a\n    commands:\n      - name: b\n        run: [x]\n  - name: a\n    commands:\n      - name: c\n        run: [x]\n", "group 'a' is defined twice" },
        { "name: x\n", "missing required key 'groups'" },
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        rc = load(bad[i].text, &s, &err);
        CHECK_CASE(bad[i].want, rc == -1);
        if (rc == -1) CHECK_CONTAINS(err.msg, bad[i].want);
        else sv_stack_free(&s);
    }
}

static void test_backoff_and_failed(void)
{
    sv_policy_t pol;
    sv_policy_default(&pol);
    pol.backoff_initial_s = 0.1; pol.backoff_max_s = 1.0; pol.stable_s = 10; pol.max_failures = 5;
    CHECK_NEAR(sv_backoff_s(&pol, 1), 0.1, 1e-12);
    CHECK_NEAR(sv_backoff_s(&pol, 3), 0.4, 1e-12);
    CHECK_NEAR(sv_backoff_s(&pol, 5), 1.0, 1e-12);     /* capped */
    CHECK_NEAR(sv_backoff_s(&pol, 100), 1.0, 1e-12);

    sv_proc_t p;
    sv_proc_init(&p, &pol);
    int64_t t = S(100);
    sv_proc_start(&p, t);
    CHECK(p.state == SV_WAITING);
    CHECK(sv_proc_tick(&p, t, 0) == SV_DO_NOTHING);      /* gate closed */
    CHECK(sv_proc_tick(&p, t, 1) == SV_DO_START);
    sv_proc_started(&p, 11, t);
    CHECK(p.state == SV_STARTING && !sv_proc_ready(&p));
    sv_proc_heartbeat(&p, t + S(0.01), 0);     /* alive (its bus is open), maybe still loading */
    CHECK(p.state == SV_STARTING && !sv_proc_ready(&p));
    sv_proc_heartbeat(&p, t + S(1.2), 1);      /* a beat from its running loop: ready */
    CHECK(p.state == SV_RUNNING && sv_proc_ready(&p) && p.restarts == 0);

    /* Quick failures: delays 0.1, 0.2, 0.4, 0.8, then FAILED at the 5th. */
    double want[] = { 0.1, 0.2, 0.4, 0.8 };
    for (int k = 0; k < 4; k++) {
        t += S(1);
        sv_proc_exited(&p, 1, t);
        CHECK(p.state == SV_BACKOFF && p.failures == k + 1);
        CHECK(sv_proc_tick(&p, t + S(want[k]) - 1, 1) == SV_DO_NOTHING);
        CHECK(sv_proc_tick(&p, t + S(want[k]), 1) == SV_DO_START);
        t += S(want[k]);
        sv_proc_started(&p, 20 + k, t);
        CHECK(p.restarts == k + 1);
    }
    t += S(1);
    sv_proc_exited(&p, -9, t);
    CHECK(p.state == SV_FAILED && p.last_exit == -9);
    CHECK_CONTAINS(p.detail, "FAILED after 5 failures");
    CHECK(sv_proc_tick(&p, t + S(1000), 1) == SV_DO_NOTHING);     /* FAILED stays FAILED ... */
    sv_proc_start(&p, t + S(5));                                   /* ... until an operator's start */
    CHECK(p.state == SV_WAITING && p.failures == 0);
    CHECK(sv_proc_tick(&p, t + S(5), 1) == SV_DO_START);
    t += S(5);
    sv_proc_started(&p, 30, t);

    /* A stable run resets the backoff: the next failure waits the initial delay. */
    sv_proc_heartbeat(&p, t + S(1), 1);
    sv_proc_exited(&p, 2, t + S(1));
    CHECK(p.failures == 1);
    sv_proc_tick(&p, t + S(1.1), 1);
    sv_proc_started(&p, 31, t + S(1.1));
    sv_proc_exited(&p, 2, t + S(1.5));
    CHECK(p.failures == 2);
    sv_proc_tick(&p, t + S(1.7), 1);
    sv_proc_started(&p, 32, t + S(1.7));
    sv_proc_exited(&p, 2, t + S(20));      /* ran 18.3 s >= stable_s */
    CHECK(p.failures == 1 && p.state == SV_BACKOFF);
    CHECK(p.restart_at_us == t + S(20) + S(0.1));
}

static void test_hang_and_stop(void)
{
    sv_policy_t pol;
    sv_policy_default(&pol);
    pol.heartbeat_s = 2; pol.start_grace_s = 10; pol.stop_timeout_s = 3;
    sv_proc_t p;
    sv_proc_init(&p, &pol);
    int64_t t = S(50);
    sv_proc_start(&p, t);
    sv_proc_tick(&p, t, 1);
    sv_proc_started(&p, 42, t);
    /* No STATUS during the grace: no verdict (a map still loading). */
    CHECK(sv_proc_tick(&p, t + S(9.9), 1) == SV_DO_NOTHING);
    CHECK(sv_proc_tick(&p, t + S(10.1), 1) == SV_DO_TERM);
    CHECK(p.state == SV_STOPPING);
    CHECK_CONTAINS(p.detail, "hang: no STATUS");
    CHECK(sv_proc_tick(&p, t + S(13.0), 1) == SV_DO_NOTHING);
    CHECK(sv_proc_tick(&p, t + S(13.2), 1) == SV_DO_KILL);
    CHECK(sv_proc_tick(&p, t + S(13.3), 1) == SV_DO_NOTHING);     /* SIGKILL once */
    sv_proc_exited(&p, -9, t + S(13.3));
    CHECK(p.state == SV_BACKOFF && p.failures == 1);               /* a hang counts as a failure */
    t += S(14);
    CHECK(sv_proc_tick(&p, t, 1) == SV_DO_START);
    sv_proc_started(&p, 43, t);
    /* Beats after the grace keep it alive; a silence of heartbeat_s is a hang. */
    for (int k = 1; k <= 12; k++) sv_proc_heartbeat(&p, t + S(k), 1);
    CHECK(sv_proc_tick(&p, t + S(13.9), 1) == SV_DO_NOTHING);
    CHECK(sv_proc_tick(&p, t + S(14.1), 1) == SV_DO_TERM);

    /* An operator's stop: STOPPED, no restart; restart: a new run at once, not a failure. */
    sv_proc_t q;
    sv_proc_init(&q, &pol);
    sv_proc_start(&q, t);
    sv_proc_tick(&q, t, 1);
    sv_proc_started(&q, 50, t);
    sv_proc_heartbeat(&q, t + S(0.1), 1);
    sv_proc_heartbeat(&q, t + S(0.5), 1);
    sv_proc_restart(&q, t + S(1));
    CHECK(q.state == SV_STOPPING);
    CHECK(sv_proc_tick(&q, t + S(1), 1) == SV_DO_TERM);           /* SIGTERM once, */
    CHECK(sv_proc_tick(&q, t + S(1.1), 1) == SV_DO_NOTHING);      /* then wait for the exit */
    sv_proc_exited(&q, 0, t + S(1.2));
    CHECK(q.state == SV_BACKOFF && q.failures == 0);
    CHECK(sv_proc_tick(&q, t + S(1.2), 1) == SV_DO_START);
    sv_proc_started(&q, 51, t + S(1.2));
    sv_proc_stop(&q, t + S(2));
    CHECK(q.state == SV_STOPPING);
    CHECK(sv_proc_tick(&q, t + S(2), 1) == SV_DO_TERM);
    sv_proc_exited(&q, 0, t + S(2.1));
    CHECK(q.state == SV_STOPPED && q.restarts == 1);
    CHECK(sv_proc_tick(&q, t + S(100), 1) == SV_DO_NOTHING);

    /* restart: on-failure treats exit 0 as the end (lcm-logplayer at the end of its log). */
    pol.restart = SV_RESTART_ON_FAILURE;
    sv_proc_t r;
    sv_proc_init(&r, &pol);
    sv_proc_start(&r, t);
    sv_proc_tick(&r, t, 1);
    sv_proc_started(&r, 60, t);
    sv_proc_exited(&r, 0, t + S(30));
    CHECK(r.state == SV_EXITED && sv_proc_ready(&r));
}

int main(void)
{
    if (!mkdtemp(dir)) { perror("mkdtemp"); return 1; }
    test_stack();
    test_backoff_and_failed();
    test_hang_and_stop();
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0) fprintf(stderr, "could not remove %s\n", dir);
    return pb_check_report("test_supervisor");
}
