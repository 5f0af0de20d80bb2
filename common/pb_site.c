/* Site: reads DIR/site.yaml strictly and resolves its file names against DIR. */
#include "pb_site.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "pb_config.h"

int pb_site_load(const char *dir, pb_site_t *s, pb_err_t *err)
{
    memset(s, 0, sizeof *s);
    struct stat sb;
    if (stat(dir, &sb) != 0 || !S_ISDIR(sb.st_mode))
        return pb_err_set(err, "%s: site folder not found", dir);
    snprintf(s->dir, sizeof s->dir, "%s", dir);
    char path[1100];
    snprintf(path, sizeof path, "%s/site.yaml", dir);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    int rc = -1;
    struct {
        char name[64], description[256], route[256], world[256], ground[256];
        const pb_cfg_node_t *georef, *map;
    } top = { "", "", "route.yaml", "world.yaml", "ground.yaml", 0, 0 };
#define T(key, type, field, len, req) { key, type, offsetof(typeof(top), field), len, req }
    const pb_cfg_field_t f[] = {
        T("name", PB_CFG_STRING, name, sizeof top.name, 1),
        T("description", PB_CFG_STRING, description, sizeof top.description, 0),
        T("georef", PB_CFG_NODE, georef, 0, 1),
        T("route", PB_CFG_STRING, route, sizeof top.route, 0),
        T("world", PB_CFG_STRING, world, sizeof top.world, 0),
        T("ground", PB_CFG_STRING, ground, sizeof top.ground, 0),
        T("map", PB_CFG_NODE, map, 0, 0), PB_CFG_END };
#undef T
    if (pb_cfg_read(pb_cfg_root(cfg), f, &top, err)) goto out;
    const pb_cfg_field_t g[] = {
        { "lat0_deg", PB_CFG_DOUBLE, offsetof(pb_georef_t, lat0_deg), 0, 1 },
        { "lon0_deg", PB_CFG_DOUBLE, offsetof(pb_georef_t, lon0_deg), 0, 1 },
        { "alt0_m", PB_CFG_DOUBLE, offsetof(pb_georef_t, alt0_m), 0, 1 },
        { "yaw_deg", PB_CFG_DOUBLE, offsetof(pb_georef_t, yaw_deg), 0, 0 },
        { "geoid_height_m", PB_CFG_DOUBLE, sizeof(pb_georef_t), 0, 0 },  /* lands in s->geoid_height_m */
        PB_CFG_END };
    struct { pb_georef_t geo; double geoid; } gr = { { 0, 0, 0, 0 }, 0 };
    _Static_assert(offsetof(typeof(gr), geoid) == sizeof(pb_georef_t), "geoid follows georef");
    if (pb_cfg_read(top.georef, g, &gr, err)) goto out;
    if (fabs(gr.geo.lat0_deg) > 90 || fabs(gr.geo.lon0_deg) > 180) {
        pb_err_set(err, "%s:%d: georef: lat0_deg in -90..90, lon0_deg in -180..180", path, pb_node_line(top.georef));
        goto out;
    }
    s->geo = gr.geo;
    s->geoid_height_m = gr.geoid;
    if (top.map) {  /* read here only to refuse typos; the simulator does not use the map */
        struct { char file[256], frame[32]; double voxel; } m;
        const pb_cfg_field_t mf[] = {
            { "file", PB_CFG_STRING, offsetof(typeof(m), file), sizeof m.file, 1 },
            { "frame", PB_CFG_STRING, offsetof(typeof(m), frame), sizeof m.frame, 0 },
            { "voxel_m", PB_CFG_DOUBLE, offsetof(typeof(m), voxel), 0, 0 }, PB_CFG_END };
        if (pb_cfg_read(top.map, mf, &m, err)) goto out;
    }
    snprintf(s->name, sizeof s->name, "%s", top.name);
    snprintf(s->route_path, sizeof s->route_path, "%s/%s", dir, top.route);
    snprintf(s->world_path, sizeof s->world_path, "%s/%s", dir, top.world);
    snprintf(s->ground_path, sizeof s->ground_path, "%s/%s", dir, top.ground);
    rc = 0;
out:
    pb_cfg_free(cfg);
    return rc;
}
