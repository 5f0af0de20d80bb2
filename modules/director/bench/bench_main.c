/* bench-director: cost of one POSE update of the director core (make bench-director).
 *
 * A synthetic scenario of 1,000 triggers (box, cylinder and prism volumes spread
 * along the default route, each trigger an OR of two AND groups that never both
 * hold, so every trigger is evaluated at every pose: the worst case) and 200
 * walking agents (50 of them arrival-synchronised) is written to a temporary
 * file, loaded through the normal loader, and driven by 100 Hz poses along the
 * route at 10 m/s. The target (issue "Director") names no baseline program; for scale
 * the table also shows the shipped scenario cw01_look_and_cross on the same poses, a
 * reference row, not a baseline. The table is written to build/bench/director.json too. One core: CPU time of the thread per dir_pose call (CLOCK_THREAD_CPUTIME_ID), so
 * that other processes on a shared machine do not count.
 *
 *   bench-director [--site DIR] [--laps N] [--vehicle FILE] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "director/core/director.h"
#include "pb_clock.h"
#include "pb_opt.h"
#include "pb_route.h"
#include "pb_site.h"
#include "pb_vehicle.h"

static void on_event(const dir_event_t *ev, void *user) { (*(long *)user)++; (void)ev; }

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The synthetic worst case. */
static int write_big(const char *path, const pb_route_t *r, int ntrig, int nagents)
{
    FILE *f = fopen(path, "w");
    if (!f) return -1;
    fprintf(f, "scenario: bench_big\nvolumes:\n");
    for (int i = 0; i < ntrig; i++) {
        pb_route_point_t p;
        pb_route_eval(r, (i + 0.5) * r->length / ntrig, &p);
        double side = (i % 3 == 0) ? 0 : (i % 3 == 1 ? 4.0 : -4.0);
        double x = p.x - side * sin(p.yaw), y = p.y + side * cos(p.yaw);
        if (i % 3 == 0)
            fprintf(f, "  - {id: v%d, type: box, center: [%.3f, %.3f], yaw_deg: %.2f, size: [1.5, 3.0, 3.0]}\n", i, x, y, p.yaw * 180 / M_PI);
        else if (i % 3 == 1)
            fprintf(f, "  - {id: v%d, type: cylinder, center: [%.3f, %.3f], radius: 1.0, height: 2.0}\n", i, x, y);
        else
            fprintf(f, "  - {id: v%d, type: prism, points: [[%.3f, %.3f], [%.3f, %.3f], [%.3f, %.3f]], z: [0, 2]}\n", i,
                    x - 1, y - 1, x + 1, y - 1, x, y + 1);
    }
    fprintf(f, "agents:\n");
    for (int i = 0; i < nagents; i++) {
        pb_route_point_t p;
        pb_route_eval(r, (i + 0.25) * r->length / nagents, &p);
        fprintf(f, "  - {id: a%d, kind: pedestrian, model: m, start: [%.3f, %.3f]}\n", i, p.x - 7 * sin(p.yaw), p.y + 7 * cos(p.yaw));
    }
    fprintf(f, "behaviours:\n");
    for (int i = 0; i < nagents; i++) {
        pb_route_point_t p, q;
        pb_route_eval(r, (i + 0.25) * r->length / nagents, &p);
        pb_route_eval(r, (i + 0.25) * r->length / nagents + 20, &q);
        fprintf(f, "  - id: b%d\n    agent: a%d\n    path:\n", i, i);
        for (int k = 0; k < 6; k++) {
            const pb_route_point_t *e = (k % 2) ? &p : &q;
            fprintf(f, "      - {to: [%.3f, %.3f], speed: 1.3, wait_s: 0.5, gesture: look_left}\n", e->x - 7 * sin(e->yaw), e->y + 7 * cos(e->yaw));
        }
        if (i % 4 == 0 && r->nstops)
            fprintf(f, "    sync: {mark: 5, stop_line: %s}\n", r->stops[(i / 4) % r->nstops].id);
    }
    fprintf(f, "triggers:\n  - id: go\n    when: {type: time, above: 0.0}\n    actions:\n");
    for (int i = 0; i < nagents; i++) fprintf(f, "      - {type: start, behaviour: b%d}\n", i);
    for (int i = 1; i < ntrig; i++) {
        pb_route_point_t p;
        pb_route_eval(r, (i + 0.5) * r->length / ntrig, &p);
        fprintf(f, "  - id: t%d\n    when:\n      any:\n"
                   "        - all: [{type: enter, volume: v%d, edge: rising}, {type: speed, above: 50}]\n"
                   "        - all: [{type: distance, point: [%.3f, %.3f], below: 0.2}, {type: standstill, duration_s: 30}]\n"
                   "    actions:\n      - {type: emit, event: e%d}\n", i, i, p.x, p.y, i);
    }
    return fclose(f);
}

typedef struct { double median, p99, max; long events; int n; } result_t;

static int run(const char *path, const pb_route_t *r, const dir_vehicle_t *veh, int laps, result_t *res)
{
    pb_err_t err;
    sc_scenario_t sc;
    if (sc_load(path, r, &sc, &err)) { fprintf(stderr, "bench-director: %s\n", err.msg); return -1; }
    long events = 0;
    director_t *d = dir_create(&sc, r, veh, on_event, &events, &err);
    if (!d) { fprintf(stderr, "bench-director: %s\n", err.msg); sc_free(&sc); return -1; }
    const double v = 10.0, dt = 0.01;
    int n = (int)(laps * r->length / (v * dt));
    double *t = malloc(n * sizeof *t);
    int64_t t0 = 1714572000000000LL;
    for (int i = 0; i < n; i++) {
        pb_route_point_t p;
        pb_route_eval(r, i * v * dt, &p);
        dir_pose_t pose = { .utime = t0 + (int64_t)i * 10000, .pos = { p.x, p.y, 0 },
                            .q = { cos(p.yaw / 2), 0, 0, sin(p.yaw / 2) }, .vel = { v * cos(p.yaw), v * sin(p.yaw), 0 } };
        double a = pb_clock_thread_cpu_ms() * 1e3;
        dir_pose(d, &pose, &err);
        t[i] = pb_clock_thread_cpu_ms() * 1e3 - a;
    }
    qsort(t, n, sizeof *t, cmp_d);
    res->median = t[n / 2];
    res->p99 = t[(int)(0.99 * (n - 1))];
    res->max = t[n - 1];
    res->events = events;
    res->n = n;
    free(t);
    dir_destroy(d);
    sc_free(&sc);
    return 0;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: bench-director [--site DIR] [--laps N] [--vehicle FILE]\n"
               "Cost of one POSE update of the director core: 1,000 triggers and 200 agents\n"
               "against the shipped cw01 scenario, 100 Hz poses along the route at 10 m/s.\n");
}

int main(int argc, char **argv)
{
    const char *site_dir = PB_SOURCE_DIR "/maps/default";
    const char *vehicle = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    int laps = 1;
    const pb_opt_t opts[] = {
        PB_OPT_STRING("site", &site_dir), PB_OPT_INT("laps", &laps, 1, 20), PB_OPT_STRING("vehicle", &vehicle), PB_OPT_END,
    };
    int parsed = pb_opt_parse("bench-director", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    pb_site_t site;
    pb_route_t r;
    pb_vehicle_t veh;
    if (pb_site_load(site_dir, &site, &err) || pb_route_load(site.route_path, &r, &err) || pb_vehicle_load(vehicle, &veh, &err)) {
        fprintf(stderr, "bench-director: %s\n", err.msg);
        return 1;
    }
    dir_vehicle_t dv = { veh.length, veh.width, veh.height, veh.rear_overhang };
    char big[] = "/tmp/bench-director-XXXXXX.yaml";
    int fd = mkstemps(big, 5);
    if (fd < 0) { perror("mkstemps"); return 1; }
    close(fd);
    if (write_big(big, &r, 1000, 200)) { perror(big); return 1; }
    char base[1300];
    snprintf(base, sizeof base, "%s/scenarios/cw01_look_and_cross.yaml", site_dir);
    result_t rb, rg;
    if (run(base, &r, &dv, laps, &rb) || run(big, &r, &dv, laps, &rg)) { unlink(big); return 1; }
    unlink(big);
    printf("Director core, one POSE update (dir_pose: triggers, agents, collisions), %d poses at 100 Hz, thread CPU time\n", rg.n);
    printf("%-34s %9s %9s %9s %8s\n", "scenario", "median_us", "p99_us", "max_us", "events");
    printf("%-34s %9.1f %9.1f %9.1f %8ld\n", "reference: cw01 (5 trig, 3 agents)", rb.median, rb.p99, rb.max, rb.events);
    printf("%-34s %9.1f %9.1f %9.1f %8ld\n", "1000 triggers, 200 agents", rg.median, rg.p99, rg.max, rg.events);
    printf("target p99 <= 500 us: %s (%.1f us)\n", rg.p99 <= 500 ? "met" : "NOT met", rg.p99);
    const char *json = PB_SOURCE_DIR "/build/bench/director.json";
    FILE *jf = fopen(json, "w");
    if (!jf) { fprintf(stderr, "bench-director: %s: cannot write (make creates build/bench)\n", json); return 1; }
    fprintf(jf, "{\"poses\": %d, \"target_p99_us\": 500,\n \"rows\": [\n"
                "  {\"scenario\": \"cw01 (reference)\", \"median_us\": %.2f, \"p99_us\": %.2f, \"max_us\": %.2f, \"events\": %ld},\n"
                "  {\"scenario\": \"1000 triggers, 200 agents\", \"median_us\": %.2f, \"p99_us\": %.2f, \"max_us\": %.2f, \"events\": %ld}]}\n",
            rg.n, rb.median, rb.p99, rb.max, rb.events, rg.median, rg.p99, rg.max, rg.events);
    fclose(jf);
    printf("written: %s\n", json);
    pb_route_free(&r);
    return 0;
}
