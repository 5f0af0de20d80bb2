/* scenario-check: validates scenario files against their site, with file:line errors.
 *   scenario-check --site SITE_DIR [--vehicle FILE] FILE...   (no FILE: every scenario of the site) */
#include <glob.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "check.h"
#include "pb_opt.h"
#include "pb_route.h"
#include "pb_site.h"
#include "pb_vehicle.h"

static void usage(FILE *f)
{
    fprintf(f, "usage: scenario-check --site SITE_DIR [--vehicle FILE] [SCENARIO.yaml ...]\n"
               "Checks scenario files (docs/scenarios.md) against the site: syntax, unknown keys and\n"
               "ids, values out of range (the director's own loader), then volumes off the route (the\n"
               "car's footprint never touches them), arrival-synchronised agents that cannot reach\n"
               "their marks, behaviours never started. Without files: every SITE_DIR/scenarios/*.yaml.\n"
               "Prints FILE:LINE: error|warning: ...; exit 0 if no errors, 1 otherwise, 2 on bad usage.\n"
               "  --site DIR       site folder (site.yaml, route.yaml)\n"
               "  --vehicle FILE   vehicle file (default %s/vehicles/prius2017.yaml)\n"
               "  -h, --help       this text\n", PB_SOURCE_DIR);
}

static void print(int is_error, const char *file, int line, const char *msg, void *user)
{
    (void)user;
    printf("%s:%d: %s: %s\n", file, line, is_error ? "error" : "warning", msg);
}

int main(int argc, char **argv)
{
    const char *site_dir = NULL, *vehicle = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    const pb_opt_t opts[] = { PB_OPT_REQUIRED("site", &site_dir), PB_OPT_STRING("vehicle", &vehicle), PB_OPT_END };
    int parsed = pb_opt_parse("scenario-check", opts, usage, PB_OPT_ARGS, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    pb_site_t site;
    pb_route_t route;
    pb_vehicle_t veh;
    if (pb_site_load(site_dir, &site, &err) || pb_route_load(site.route_path, &route, &err)) { fprintf(stderr, "scenario-check: %s\n", err.msg); return 1; }
    if (pb_vehicle_load(vehicle, &veh, &err)) { fprintf(stderr, "scenario-check: %s\n", err.msg); return 1; }
    check_vehicle_t cv = { veh.length, veh.width, veh.height, veh.rear_overhang };
    glob_t g;
    memset(&g, 0, sizeof g);
    int nfiles = argc - optind;
    char **files = argv + optind;
    if (nfiles == 0) {
        char pat[1200];
        snprintf(pat, sizeof pat, "%s/scenarios/*.yaml", site_dir);
        if (glob(pat, 0, NULL, &g) != 0) { fprintf(stderr, "scenario-check: no scenarios in %s/scenarios/\n", site_dir); return 1; }
        nfiles = (int)g.gl_pathc;
        files = g.gl_pathv;
    }
    int bad = 0;
    for (int i = 0; i < nfiles; i++) {
        sc_scenario_t sc;
        if (sc_load(files[i], &route, &sc, &err)) {
            printf("%s: error\n", err.msg);   /* the loader's message starts with FILE:LINE */
            bad++;
            continue;
        }
        int e = check_scenario(&sc, &route, &cv, print, NULL);
        printf("%s: %s: %d volumes, %d agents, %d behaviours, %d triggers: %s\n", files[i], sc.id, sc.nvolumes, sc.nagents,
               sc.nbehaviours, sc.ntriggers, e ? "errors" : "ok");
        bad += e > 0;
        sc_free(&sc);
    }
    globfree(&g);
    pb_route_free(&route);
    return bad ? 1 : 0;
}
