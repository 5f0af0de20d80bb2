/* Unit tests of the mapper's odometry (modules/mapper/core/odometry) on a long street: the
 * car drives 260 m, three times the local map's radius, so its cells are dropped behind it
 * (taken out of the index where they lie, and now and then compacted). Sweeps 0.5 s apart
 * (a dataset's keyframes: the registration map is rebuilt with each) and 0.1 s apart (a
 * LiDAR: rebuilt on another thread every 10 m). The poses stay on the truth, and a state
 * saved mid-drive (with cells dropped in it), restored and driven on gives the same poses
 * and the same state bytes as the drive that was not stopped. */
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "mapper/core/odometry.h"
#include "pb_check.h"

using Vec3 = Eigen::Vector3d;

/* A street along x: the road, house fronts at y = +-9 with doors and bays (no two stretches
 * alike), and poles at uneven spacing on both sides. */
static std::vector<Vec3> make_street(double length)
{
    std::vector<Vec3> w;
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(0, 1);
    for (double x = -40; x <= length + 40; x += 0.4)
        for (double y = -9; y <= 9; y += 0.4) w.push_back(Vec3(x, y, 0));
    for (int side = -1; side <= 1; side += 2) {
        double x = -40;
        while (x < length + 40) {
            const double run = 4 + 8 * u(rng), depth = 1.5 * u(rng), h = 5 + 6 * u(rng);
            const double y = side * (9 + depth);
            for (double s = 0; s < run; s += 0.2)
                for (double z = 0.1; z < h; z += 0.25) w.push_back(Vec3(x + s, y, z));
            for (double z = 0.1; z < h; z += 0.25)   /* the step between two fronts */
                for (double d = 0; d < 1.5; d += 0.2) w.push_back(Vec3(x, side * (9 + d), z));
            x += run;
        }
        for (double px = -40 + 5 * u(rng); px < length + 40; px += 5 + 7 * u(rng))
            for (double z = 0; z < 4; z += 0.1)
                for (int k = 0; k < 8; k++)
                    w.push_back(Vec3(px + 0.1 * std::cos(k * M_PI / 4), side * 7 + 0.1 * std::sin(k * M_PI / 4), z));
    }
    return w;
}

/* The sweep from base at (x, 0, 0) heading +x: the world within 40 m, in base. */
static std::vector<float> sweep_at(const std::vector<Vec3> &world, double x)
{
    std::vector<float> xyz;
    for (const Vec3 &p : world)
        if (std::fabs(p.x() - x) < 40) xyz.insert(xyz.end(), {(float)(p.x() - x), (float)p.y(), (float)p.z()});
    return xyz;
}

struct Drive {
    std::vector<Eigen::Isometry3d> poses;
    std::vector<uint8_t> state_mid, state_end;   /* pb_odom_save after sweep `mid` and at the end */
};

/* Drives the street at 8 m/s, sweeps dt apart; with restart, the odometry is saved after
 * sweep `mid`, destroyed, and restored from those bytes. */
static bool drive(const std::vector<Vec3> &world, double dt, int sweeps, int mid, bool restart, Drive *out)
{
    pb_err_t err;
    pb_odom_t *o = pb_odom_create(nullptr, nullptr);
    for (int i = 0; i < sweeps; i++) {
        const double x = 8.0 * dt * i;
        std::vector<float> xyz = sweep_at(world, x);
        std::vector<int32_t> off(xyz.size() / 3, 0);
        pb_odom_result_t r;
        if (CHECK_OK(pb_odom_add(o, (int64_t)(1e6 + i * dt * 1e6), xyz.data(), off.data(), off.size(), nullptr, &r, &err),
                     err.msg)) {
            pb_odom_destroy(o);
            return false;
        }
        out->poses.push_back(r.pose);
        if (i == mid) {
            pb_odom_save(o, &out->state_mid);
            if (restart) {
                pb_odom_destroy(o);
                o = pb_odom_restore(out->state_mid.data(), out->state_mid.size(), nullptr, nullptr, &err);
                CHECK(o != nullptr);
                if (!o) return false;
            }
        }
    }
    pb_odom_save(o, &out->state_end);
    pb_odom_destroy(o);
    return true;
}

static void test_long_street(double dt, int sweeps, double bound_m)
{
    const std::vector<Vec3> world = make_street(8.0 * dt * sweeps);
    const int mid = sweeps * 3 / 4;   /* 195 m on: cells dropped behind the car since 100 m */
    Drive a, b;
    if (!drive(world, dt, sweeps, mid, false, &a) || !drive(world, dt, sweeps, mid, true, &b)) return;
    double worst = 0;
    for (int i = 0; i < sweeps; i++)
        worst = std::max(worst, (a.poses[(size_t)i].translation() - Vec3(8.0 * dt * i, 0, 0)).norm());
    std::printf("odometry, sweeps %.1f s apart: %d sweeps over %.0f m, position error at most %.3f m\n", dt, sweeps,
                8.0 * dt * (sweeps - 1), worst);
    CHECK(worst < bound_m);
    bool same = a.poses.size() == b.poses.size();
    for (size_t i = 0; same && i < a.poses.size(); i++)
        same = std::memcmp(a.poses[i].data(), b.poses[i].data(), sizeof(double) * 16) == 0;
    CHECK(same);
    CHECK(a.state_end == b.state_end);
    /* a restored state saves to its own bytes again */
    pb_err_t err;
    pb_odom_t *o = pb_odom_restore(a.state_mid.data(), a.state_mid.size(), nullptr, nullptr, &err);
    CHECK(o != nullptr);
    std::vector<uint8_t> again;
    if (o) pb_odom_save(o, &again);
    CHECK(again == a.state_mid);
    pb_odom_destroy(o);
}

int main()
{
    /* the bounds: three times the errors measured (0.051 and 0.022 m, 7 Dec 2026) */
    test_long_street(0.5, 66, 0.15);    /* 260 m in keyframes 4 m apart */
    test_long_street(0.1, 330, 0.07);   /* 263 m in sweeps 0.8 m apart */
    return pb_check_report("test_mapper_odometry");
}
