/* Reads a vehicle file strictly: unknown keys and wrong types fail with file:line. */
#include "pb_vehicle.h"

#include <libgen.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "pb_config.h"

#define F(key, type, field, len, req) { key, type, offsetof(pb_vehicle_t, field), len, req }

static void make_tf(const double xyz[3], const double rpy_deg[3], pb_transform_t *tf)
{
    const double d2r = M_PI / 180.0;
    memcpy(tf->t, xyz, sizeof tf->t);
    pb_quat_from_rpy(rpy_deg[0] * d2r, rpy_deg[1] * d2r, rpy_deg[2] * d2r, tf->q);
}

int pb_vehicle_load(const char *path, pb_vehicle_t *v, pb_err_t *err)
{
    memset(v, 0, sizeof *v);
    strcpy(v->lidar_model, "OS1-64");
    /* Defaults for the simulation block: the values of vehicles/prius2017.yaml. */
    v->imu_rate_hz = 200; v->accel_noise = 0.02; v->gyro_noise = 0.001;
    v->accel_bias = 0.03; v->gyro_bias = 0.0005; v->lidar_range_noise = 0.02;
    v->lidar_dropout = 0.01; v->lidar_max_range = 120; v->gnss_noise = 1.5; v->gnss_noise_tau = 20;

    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    const pb_cfg_node_t *dims, *sensors, *sim, *lidar, *imu, *gnss;
    struct { char name[64], dbc[256]; const pb_cfg_node_t *dims, *sensors, *sim, *seat; } top = { "", "", 0, 0, 0, 0 };
    const pb_cfg_field_t top_f[] = {
        { "name", PB_CFG_STRING, offsetof(typeof(top), name), sizeof top.name, 1 },
        { "dbc", PB_CFG_STRING, offsetof(typeof(top), dbc), sizeof top.dbc, 0 },
        { "dimensions", PB_CFG_NODE, offsetof(typeof(top), dims), 0, 1 },
        { "sensors", PB_CFG_NODE, offsetof(typeof(top), sensors), 0, 1 },
        { "simulation", PB_CFG_NODE, offsetof(typeof(top), sim), 0, 0 },
        { "seat", PB_CFG_NODE, offsetof(typeof(top), seat), 0, 0 },
        PB_CFG_END };
    int rc = -1;
    if (pb_cfg_read(pb_cfg_root(cfg), top_f, &top, err)) goto out;
    memcpy(v->name, top.name, sizeof v->name);
    if (top.dbc[0] == '/' || !top.dbc[0]) {
        snprintf(v->dbc, sizeof v->dbc, "%s", top.dbc);
    } else {    /* relative to the vehicle file */
        char dir[512];
        snprintf(dir, sizeof dir, "%s", path);
        snprintf(v->dbc, sizeof v->dbc, "%s/%s", dirname(dir), top.dbc);
    }
    dims = top.dims; sensors = top.sensors; sim = top.sim;
    const pb_cfg_field_t dim_f[] = {
        F("length", PB_CFG_DOUBLE, length, 0, 1), F("width", PB_CFG_DOUBLE, width, 0, 1),
        F("height", PB_CFG_DOUBLE, height, 0, 1), F("wheelbase", PB_CFG_DOUBLE, wheelbase, 0, 1),
        F("track_front", PB_CFG_DOUBLE, track_front, 0, 1), F("track_rear", PB_CFG_DOUBLE, track_rear, 0, 1),
        F("rear_overhang", PB_CFG_DOUBLE, rear_overhang, 0, 1), PB_CFG_END };
    if (pb_cfg_read(dims, dim_f, v, err)) goto out;

    struct { const pb_cfg_node_t *lidar, *imu, *gnss; } sn = { 0 };
    const pb_cfg_field_t sen_f[] = {
        { "lidar", PB_CFG_NODE, offsetof(typeof(sn), lidar), 0, 1 },
        { "imu", PB_CFG_NODE, offsetof(typeof(sn), imu), 0, 1 },
        { "gnss", PB_CFG_NODE, offsetof(typeof(sn), gnss), 0, 1 }, PB_CFG_END };
    if (pb_cfg_read(sensors, sen_f, &sn, err)) goto out;
    lidar = sn.lidar; imu = sn.imu; gnss = sn.gnss;
    const pb_cfg_field_t lidar_f[] = {
        F("model", PB_CFG_STRING, lidar_model, sizeof v->lidar_model, 0),
        F("xyz", PB_CFG_DOUBLES, lidar_xyz, 3, 1), F("rpy_deg", PB_CFG_DOUBLES, lidar_rpy_deg, 3, 0), PB_CFG_END };
    const pb_cfg_field_t imu_f[] = {
        F("xyz", PB_CFG_DOUBLES, imu_xyz, 3, 1), F("rpy_deg", PB_CFG_DOUBLES, imu_rpy_deg, 3, 0), PB_CFG_END };
    const pb_cfg_field_t gnss_f[] = {
        F("xyz", PB_CFG_DOUBLES, gnss_xyz, 3, 1), F("rpy_deg", PB_CFG_DOUBLES, gnss_rpy_deg, 3, 0), PB_CFG_END };
    if (pb_cfg_read(lidar, lidar_f, v, err) || pb_cfg_read(imu, imu_f, v, err) || pb_cfg_read(gnss, gnss_f, v, err))
        goto out;
    if (sim) {
        const pb_cfg_field_t sim_f[] = {
            F("imu_rate_hz", PB_CFG_DOUBLE, imu_rate_hz, 0, 0), F("accel_noise", PB_CFG_DOUBLE, accel_noise, 0, 0),
            F("gyro_noise", PB_CFG_DOUBLE, gyro_noise, 0, 0), F("accel_bias", PB_CFG_DOUBLE, accel_bias, 0, 0),
            F("gyro_bias", PB_CFG_DOUBLE, gyro_bias, 0, 0),
            F("lidar_range_noise", PB_CFG_DOUBLE, lidar_range_noise, 0, 0),
            F("lidar_dropout", PB_CFG_DOUBLE, lidar_dropout, 0, 0),
            F("lidar_max_range", PB_CFG_DOUBLE, lidar_max_range, 0, 0),
            F("gnss_noise", PB_CFG_DOUBLE, gnss_noise, 0, 0), F("gnss_noise_tau", PB_CFG_DOUBLE, gnss_noise_tau, 0, 0),
            PB_CFG_END };
        if (pb_cfg_read(sim, sim_f, v, err)) goto out;
    }
    if (top.seat) {     /* the driver's eye: the occlusion module's viewer without HEAD_POSE */
        const pb_cfg_field_t seat_f[] = { F("eye_xyz", PB_CFG_DOUBLES, seat_eye_xyz, 3, 1), PB_CFG_END };
        if (pb_cfg_read(top.seat, seat_f, v, err)) goto out;
        v->has_seat_eye = 1;
    }
    if (v->wheelbase <= 0 || v->track_front <= 0 || v->track_rear <= 0 || v->length <= v->rear_overhang) {
        pb_err_set(err, "%s:%d: dimensions: wheelbase, tracks and length must be positive", path, pb_node_line(dims));
        goto out;
    }
    if (v->imu_rate_hz < 1 || v->imu_rate_hz > 2000 || v->gnss_noise_tau <= 0 || v->lidar_max_range <= 1) {
        pb_err_set(err, "%s:%d: simulation: imu_rate_hz in 1..2000, gnss_noise_tau > 0, lidar_max_range > 1",
                   path, sim ? pb_node_line(sim) : 1);
        goto out;
    }
    make_tf(v->lidar_xyz, v->lidar_rpy_deg, &v->base_from_lidar);
    make_tf(v->imu_xyz, v->imu_rpy_deg, &v->base_from_imu);
    make_tf(v->gnss_xyz, v->gnss_rpy_deg, &v->base_from_gnss);
    rc = 0;
out:
    pb_cfg_free(cfg);
    return rc;
}

void pb_vehicle_body_box(const pb_vehicle_t *v, double margin_m, double box[6])
{
    const double m = margin_m, ro = v->rear_overhang;
    box[0] = -ro - m;
    box[1] = -v->width / 2 - m;
    box[2] = -m;
    box[3] = v->length - ro + m;
    box[4] = v->width / 2 + m;
    box[5] = v->height + m;
}
