/* libFuzzer target: the scenario loader on arbitrary bytes, then the director core
 * on whatever loads (a short drive through the scenario's volumes, inputs, a state
 * round trip). Every loader error must name the file.
 * fuzz-sources: modules/director/core/scenario.c modules/director/core/director.c modules/director/core/geom.c common/pb_config.c common/pb_err.c common/pb_route.c common/pb_ground.c
 * fuzz-libs: -lccd */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "director/core/director.h"
#include "director/core/scenario.h"
#include "fuzz_common.h"

static void on_event(const dir_event_t *ev, void *user) { (void)ev; (*(int *)user)++; }

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *path = fuzz_input_file("scenario", ".yaml", data, size);
    if (!path) return 0;
    pb_err_t err;
    sc_scenario_t sc;
    if (sc_load(path, NULL, &sc, &err)) {
        if (!strstr(err.msg, path)) abort();
        return 0;
    }
    int nev = 0;
    dir_vehicle_t car = { 4.54, 1.76, 1.47, 1.04 };
    director_t *d = dir_create(&sc, NULL, &car, on_event, &nev, &err);
    if (d) {
        double cx = sc.nvolumes ? sc.volumes[0].bound_c[0] : 0, cy = sc.nvolumes ? sc.volumes[0].bound_c[1] : 0;
        if (!isfinite(cx) || !isfinite(cy) || fabs(cx) > 1e6 || fabs(cy) > 1e6) cx = cy = 0;
        dir_agent_out_t *out = calloc(sc.nagents + 1, sizeof *out);
        for (int i = 0; i < 60; i++) {
            double x = cx - 15 + i * 0.5;
            dir_pose_t p = { .utime = 1000000 + i * 100000, .pos = { x, cy, 0 }, .q = { 1, 0, 0, 0 }, .vel = { 5, 0, 0 } };
            if (i == 30) dir_input(d, p.utime, "proceed", 1);
            if (i == 40) { p.pos[0] += 50; }      /* a jump */
            dir_pose(d, &p, &err);
            dir_tick(d, p.utime + 50000);
            dir_agents(d, out);
        }
        static char buf[1 << 16];
        if (dir_state_write(d, buf, sizeof buf) > 0) {
            director_t *d2 = dir_create(&sc, NULL, &car, on_event, &nev, &err);
            if (dir_state_read(d2, buf, &err) != 0) abort();   /* its own state always reads back */
            dir_destroy(d2);
        }
        free(out);
        dir_destroy(d);
    }
    sc_free(&sc);
    return 0;
}
