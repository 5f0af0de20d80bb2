/* pb_vehicle: the bundled vehicle file loads; bad ones are refused with file:line. */
#include <stdlib.h>
#include <unistd.h>

#include "pb_check.h"
#include "pb_vehicle.h"

static const char *write_tmp(const char *text)
{
    static char path[] = "/tmp/pb_test_vehicle_XXXXXX.yaml";
    strcpy(path, "/tmp/pb_test_vehicle_XXXXXX.yaml");
    int fd = mkstemps(path, 5);
    if (write(fd, text, strlen(text)) < 0) return NULL;
    close(fd);
    return path;
}

int main(void)
{
    pb_vehicle_t v;
    pb_err_t err;
    CHECK(pb_vehicle_load(PB_SOURCE_DIR "/vehicles/prius2017.yaml", &v, &err) == 0);
    CHECK(strcmp(v.name, "prius2017") == 0);
    CHECK_NEAR(v.wheelbase, 2.70, 0);
    CHECK_NEAR(v.base_from_lidar.t[2], 1.95, 0);
    CHECK_NEAR(v.base_from_lidar.q[0], 1, 1e-12);
    CHECK_NEAR(v.base_from_gnss.t[0], 1.30, 0);
    CHECK_CONTAINS(v.dbc, "/vehicles/dbc/toyota_prius_2017_pt_generated.dbc");
    CHECK(access(v.dbc, R_OK) == 0);   /* resolved against the vehicle file's folder */
    CHECK_NEAR(v.imu_rate_hz, 200, 0);

    const char *good =
        "name: t\ndimensions: {length: 4, width: 2, height: 1.5, wheelbase: 2.5, track_front: 1.5, track_rear: 1.5,"
        " rear_overhang: 1}\nsensors:\n  lidar: {xyz: [1, 0, 2], rpy_deg: [0, 0, 90]}\n  imu: {xyz: [0, 0, 0]}\n"
        "  gnss: {xyz: [0, 0, 1]}\n";
    const char *p = write_tmp(good);
    CHECK(pb_vehicle_load(p, &v, &err) == 0);
    CHECK(v.dbc[0] == 0);
    CHECK_NEAR(v.base_from_lidar.q[3], sin(M_PI / 4), 1e-12);   /* yaw 90 deg */
    CHECK_NEAR(v.accel_noise, 0.02, 0);                          /* simulation defaults */
    unlink(p);

    p = write_tmp("name: t\ncolour: red\n");
    CHECK(pb_vehicle_load(p, &v, &err) == -1);
    CHECK_CONTAINS(err.msg, ":2: unknown key 'colour'");
    unlink(p);
    p = write_tmp("name: t\ndimensions: {length: 4, width: 2, height: x, wheelbase: 2.5, track_front: 1.5,"
                  " track_rear: 1.5, rear_overhang: 1}\nsensors: {}\n");
    CHECK(pb_vehicle_load(p, &v, &err) == -1);
    CHECK_CONTAINS(err.msg, ":2: height: expected a number, got 'x'");
    unlink(p);
    return pb_check_report("test_vehicle");
}
