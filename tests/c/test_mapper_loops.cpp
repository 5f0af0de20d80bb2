/* Unit tests of the mapper's loop closure (modules/mapper/core/loops): keyframes on a
 * 320 m square through a synthetic world of boxes on flat ground, each seeing the world
 * from its true pose, with odometry poses that drift (0.3 % of the path and 0.3 degrees of
 * yaw per 100 m, KISS-ICP's drift on the simulated loop and ten times the mapper's); the loop
 * at the end must be found and pull the poses back, and a false match must not. With a
 * drift of 21 m at the loop (8 degrees of yaw per 100 m) only place recognition finds it;
 * in a world that repeats itself (the corner's two roads see the same boxes) the places
 * that look alike are proposed and must be refused. */
#include <cmath>
#include <random>
#include <vector>

#include "mapper/core/loops.h"
#include "pb_check.h"
#include "places.h"
#include "registration.h"

using Vec3 = Eigen::Vector3d;

static bool on_road(const Vec3 &c) { return std::fabs(std::fabs(c.x()) - 40) < 4 || std::fabs(std::fabs(c.y()) - 40) < 4; }

/* Random boxes; repeated: each box also turned by 90, 180 and 270 degrees about (-20, -20),
 * so that the road along y = -40 (x from -40 to 0, heading +x) and the one along x = -40
 * (y from 0 to -40, heading -y) see the very same boxes: a place 280 m of path later than
 * its twin, 28-40 m from it and turned by 90 degrees. */
static std::vector<Vec3> make_world(bool repeated)
{
    std::vector<Vec3> w;
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-70, 70), size(1.0, 4.0), yaw(0, M_PI);
    for (double x = -75; x <= 75; x += 0.5)
        for (double y = -75; y <= 75; y += 0.5) w.push_back(Vec3(x, y, 0));
    const Vec3 pivot(-20, -20, 0);
    for (int b = 0; b < 120; b++) {
        Vec3 c(u(rng), u(rng), 0);
        int copies = repeated ? 4 : 1;
        bool clear = true;   /* no copy on a road */
        for (int k = 0; k < copies; k++) clear &= !on_road(pivot + Eigen::AngleAxisd(k * M_PI / 2, Vec3::UnitZ()) * (c - pivot));
        if (!clear) continue;
        double sx = size(rng), sy = size(rng), h = size(rng), a = yaw(rng);
        for (int k = 0; k < copies; k++) {
            Eigen::Matrix3d Q = Eigen::AngleAxisd(k * M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
            Vec3 ck = pivot + Q * (c - pivot);
            Eigen::Matrix3d R = Q * Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix();
            for (double z = 0.1; z <= h; z += 0.2)
                for (double s = -0.5; s <= 0.5; s += 0.2 / std::max(sx, sy)) {
                    w.push_back(ck + R * Vec3(s * sx, -sy / 2, z)); w.push_back(ck + R * Vec3(s * sx, sy / 2, z));
                    w.push_back(ck + R * Vec3(-sx / 2, s * sy, z)); w.push_back(ck + R * Vec3(sx / 2, s * sy, z));
                }
        }
    }
    return w;
}

/* The true pose at path length s on the square of side 80 m around the origin (320 m round),
 * driven counter-clockwise from (-40, -40) heading +x; base on the ground. */
static Eigen::Isometry3d true_pose(double s)
{
    s = std::fmod(s, 320.0);
    int side = (int)(s / 80);
    double along = s - side * 80;
    static const double cx[4] = {-40, 40, 40, -40}, cy[4] = {-40, -40, 40, 40};
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    double h = side * M_PI / 2;
    T.linear() = Eigen::AngleAxisd(h, Vec3::UnitZ()).toRotationMatrix();
    T.translation() = Vec3(cx[side] + along * std::cos(h), cy[side] + along * std::sin(h), 0);
    return T;
}

/* Odometry drift: the steps this much longer, and this much yaw per metre (degrees). */
struct Drift { double stretch, yaw_deg_per_m; };
static const Drift kSmallDrift = {1.003, 0.003};
static const Drift kLargeDrift = {1.0, -0.08};   /* 21-24 m off at the loop: beyond the position search */

static std::vector<pb_keyframe_t> make_keyframes(const std::vector<Vec3> &world, double path_m,
                                                 Drift drift = kSmallDrift)
{
    pb_reg_config_t red;
    pb_reg_config_default(&red);
    red.target_points = 0;
    red.scan_voxel_m = 0.5;
    std::vector<pb_keyframe_t> kf;
    Eigen::Isometry3d odo = true_pose(0), prev_true = true_pose(0);
    for (double s = 0; s <= path_m; s += 2.0) {
        Eigen::Isometry3d T = true_pose(s);
        if (s > 0) {
            /* the true step, with a drift: longer, and turned */
            Eigen::Isometry3d step = prev_true.inverse() * T;
            step.translation() *= drift.stretch;
            step.linear() = Eigen::AngleAxisd(drift.yaw_deg_per_m * M_PI / 180 * 2.0, Vec3::UnitZ()).toRotationMatrix() *
                            step.linear();
            odo = odo * step;
        }
        prev_true = T;
        std::vector<float> pts;
        Eigen::Isometry3d inv = T.inverse();
        for (const Vec3 &p : world) {
            if ((p - T.translation()).head<2>().norm() > 30) continue;
            Vec3 q = inv * p;
            pts.insert(pts.end(), {(float)q.x(), (float)q.y(), (float)q.z()});
        }
        pb_keyframe_t k;
        k.utime = (int64_t)(s * 1e5);
        k.pose = odo;
        pb_reg_downsample(pts.data(), pts.size() / 3, &red, &k.xyz);
        kf.push_back(k);
    }
    return kf;
}

static double pos_err(const Eigen::Isometry3d &a, double s) { return (a.translation() - true_pose(s).translation()).norm(); }

static void test_loop_found_and_closed(const std::vector<Vec3> &world, bool false_loop)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(world, 330);   /* once round and 10 m on */
    if (false_loop) {
        /* a keyframe near the end that sees another place (a sensor fault, a log mixed up),
         * one that is tried for a loop: its match, if any, must not pull the loop apart */
        kf[kf.size() - 8].xyz = kf[45].xyz;
    }
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &out, &rep, &err), err.msg)) return;
    CHECK(rep.verified >= 1);
    CHECK(rep.candidates >= rep.verified);
    CHECK((int)rep.loops.size() == rep.verified);
    size_t n = kf.size();
    double s_end = 2.0 * (double)(n - 1);
    double before = pos_err(kf[n - 1].pose, s_end), after = pos_err(out[n - 1], s_end);
    double worst_before = 0, worst_after = 0;
    for (size_t k = 0; k < n; k++) {
        worst_before = std::max(worst_before, pos_err(kf[k].pose, 2.0 * k));
        worst_after = std::max(worst_after, pos_err(out[k], 2.0 * k));
    }
    std::printf("loop%s: %d kept of %d tried (%d refused by the match, %d dropped as disagreeing); end error "
                "%.3f -> %.3f m, worst %.3f -> %.3f m\n", false_loop ? " with a false match" : "", rep.verified,
                rep.candidates, rep.rejected, rep.dropped, before, after, worst_before, worst_after);
    /* measured: 3 loops, end 0.861 -> 0.049 m, worst 0.949 -> 0.334 m (the middle of the loop,
     * where the correction is spread between the ends); the false match is tried, passes the
     * match (the boxes look alike) and is dropped as it disagrees with the other loops; a
     * place candidate 30 m off passes the match too and is dropped so */
    CHECK(before > 0.6);
    CHECK(after < 0.15);
    CHECK(worst_after < 1.0);
    CHECK(rep.verified >= 2);
    CHECK(rep.dropped >= (false_loop ? 1 : 0));
    for (const auto &l : rep.loops) {
        CHECK(pos_err(true_pose(2.0 * l.first), 2.0 * l.second) < 15);   /* the same place in truth */
        CHECK(!false_loop || l.second != (int)kf.size() - 8);
    }
    bool false_refused = false;
    for (const auto &l : rep.refused) false_refused |= l.second == (int)kf.size() - 8;
    CHECK(!false_loop || false_refused);
    CHECK_NEAR(out[0].translation().norm(), kf[0].pose.translation().norm(), 1e-9);   /* the first is fixed */
}

/* Largest end error and worst error of the solved poses (path s = 2 m a keyframe). */
static void errors(const std::vector<pb_keyframe_t> &kf, const std::vector<Eigen::Isometry3d> &out, double *end_before,
                   double *end_after, double *worst_after)
{
    size_t n = kf.size();
    *end_before = pos_err(kf[n - 1].pose, 2.0 * (double)(n - 1));
    *end_after = pos_err(out[n - 1], 2.0 * (double)(n - 1));
    *worst_after = 0;
    for (size_t k = 0; k < n; k++) *worst_after = std::max(*worst_after, pos_err(out[k], 2.0 * k));
}

/* A drift of 21 m at the loop (8 degrees of yaw per 100 m): no earlier keyframe of the true
 * place lies within the position search, and the descriptor (turned by the drift's 27
 * degrees) finds the loop. */
static void test_loop_found_by_place(const std::vector<Vec3> &world)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(world, 340, kLargeDrift);   /* round and 20 m on */
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &out, &rep, &err), err.msg)) return;
    double before, after, worst_after;
    errors(kf, out, &before, &after, &worst_after);
    std::printf("large drift: %d kept of %d tried (%d by place of %d), %d refused, %d dropped; end error %.3f -> "
                "%.3f m, worst after %.3f m\n", rep.verified, rep.candidates, rep.place_loops, rep.place_candidates,
                rep.rejected, rep.dropped, before, after, worst_after);
    /* measured: 2 loops, both by place (3 tried; a position candidate where the drifted
     * odometry passes 15 m from an earlier keyframe is refused); end 21.2 -> 0.24 m (0.05 m
     * with the small drift: the graph spreads 27 degrees of yaw bias), worst after 0.96 m */
    CHECK(before > 20);
    CHECK(rep.verified == rep.place_loops);   /* nothing by position */
    CHECK(rep.place_loops >= 2);
    CHECK(after < 0.75);
    CHECK(worst_after < 3.0);
}

/* The corner's two roads see the same boxes (make_world(true)): a place 280 m of path on
 * looks like one passed before (and registers on it) though 28-40 m and 90 degrees away.
 * The descriptor proposes those; they must be refused, and the true loop kept. */
static void test_look_alike_refused(const std::vector<Vec3> &repeated_world)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(repeated_world, 340, kLargeDrift);
    /* the twins (keyframe 140 + k at the place of keyframe k) look alike to the descriptor:
     * as alike as the true revisit (keyframe 160 + k) */
    pb_loc::places_config_t pcfg;
    const pb_loops_config_t lcfg;
    int alike = 0;
    for (size_t k = 0; k <= 20; k++) {
        pb_loc::place_desc_t a, b;
        pb_loc::places_describe(pcfg, kf[140 + k].xyz.data(), kf[140 + k].xyz.size() / 3, &a);
        pb_loc::places_describe(pcfg, kf[k].xyz.data(), kf[k].xyz.size() / 3, &b);
        double yaw;
        alike += pb_loc::places_compare(pcfg, a, b, &yaw) <= lcfg.place_max_distance;
    }
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &out, &rep, &err), err.msg)) return;
    auto twin = [](const std::pair<int, int> &l) { return std::fabs(2.0 * (l.second - l.first) - 280) <= 20; };
    int twins_tried = 0, twins_kept = 0, true_kept = 0;
    for (const auto &l : rep.refused) twins_tried += twin(l);
    for (const auto &l : rep.loops) {
        twins_kept += twin(l);
        true_kept += std::fabs(2.0 * (l.second - l.first) - 320) <= 20;
    }
    double before, after, worst_after;
    errors(kf, out, &before, &after, &worst_after);
    std::printf("look-alike places: %d of 21 alike to the descriptor; %d kept of %d tried (%d by place of %d), %d refused (%d of them look-alikes), "
                "%d dropped; end error %.3f -> %.3f m, worst after %.3f m\n", alike, rep.verified, rep.candidates,
                rep.place_loops, rep.place_candidates, rep.rejected, twins_tried, rep.dropped, before, after,
                worst_after);
    /* measured: all 21 twins as alike as the same place (distance 0: the boxes are copies);
     * none tried (they are 90 degrees off the odometry's heading, beyond its drift); the 2
     * true loops kept; end 21.2 -> 0.28 m */
    CHECK(alike >= 15);   /* the descriptor is fooled: the test tests the refusal */
    CHECK(twins_kept == 0);
    CHECK(true_kept >= 2 && true_kept == rep.verified);
    CHECK(after < 0.85);
}

static void test_no_loop_keeps_the_poses(const std::vector<Vec3> &world)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(world, 150);   /* half round: nothing passed twice */
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &out, &rep, &err), err.msg)) return;
    CHECK(rep.candidates == rep.place_candidates && rep.verified == 0);   /* places may look alike */
    CHECK(out.size() == kf.size());
    bool same = true;
    for (size_t k = 0; k < kf.size(); k++) same &= out[k].isApprox(kf[k].pose, 0);
    CHECK(same);
}

static void test_bad_input()
{
    std::vector<pb_keyframe_t> kf(1);
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    CHECK(pb_loops_close(kf, nullptr, &out, &rep, &err) == -1);
    CHECK_CONTAINS(err.msg, "keyframe");
}

/* Several drives: the first 150 m of the square in the map's frame; a second drive of the
 * same 150 m (another drift) in a frame of its own (500 m off, turned by 1 rad): placed, its
 * poses back in the first one's frame; a third of a world mirrored (another place): not
 * placed, its poses as given. */
static void test_drives_placed(const std::vector<Vec3> &world)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(world, 150);
    const size_t n1 = kf.size();
    Eigen::Isometry3d G = Eigen::Isometry3d::Identity();
    G.linear() = Eigen::AngleAxisd(1.0, Vec3::UnitZ()).toRotationMatrix();
    G.translation() = Vec3(500, -300, 0);
    for (pb_keyframe_t k : make_keyframes(world, 150, {0.998, -0.003})) {
        k.pose = G * k.pose;
        k.drive = 1;
        kf.push_back(k);
    }
    std::vector<Vec3> mirrored = world;
    for (Vec3 &p : mirrored) p.y() = -p.y();
    for (pb_keyframe_t k : make_keyframes(mirrored, 150)) {
        k.drive = 2;
        kf.push_back(k);
    }
    std::vector<Eigen::Isometry3d> out;
    pb_loops_report_t rep;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &out, &rep, &err), err.msg)) return;
    CHECK(rep.drives.size() == 3);
    if (rep.drives.size() != 3) return;
    double worst = 0;
    for (size_t k = n1; k < 2 * n1; k++) worst = std::max(worst, pos_err(out[k], 2.0 * (double)(k - n1)));
    std::printf("drives: placed %d %d %d (tried %d, matched %d, links %d), second drive's error max %.3f m; third: %s\n",
                rep.drives[0].placed, rep.drives[1].placed, rep.drives[2].placed, rep.drives[1].tried,
                rep.drives[1].matched, rep.drives[1].links, worst, rep.drives[2].why);
    CHECK(rep.drives[0].placed && rep.drives[1].placed && !rep.drives[2].placed);
    CHECK(rep.drives[1].links >= 2);
    CHECK(worst < 0.3);
    for (size_t k = 2 * n1; k < kf.size(); k++) CHECK((out[k].translation() - kf[k].pose.translation()).norm() == 0);
    /* drives out of order are refused */
    kf[1].drive = 1;
    CHECK(pb_loops_close(kf, nullptr, &out, &rep, &err) == -1);
}

/* The points read back through a pb_keyframe_points_t (the mapper: from keyframes.bin), a
 * few at a time, give the same loops and poses as all of them in memory; a source that
 * fails is an error, not a map without loops. */
struct Store {
    std::vector<std::vector<float>> xyz;
    long reads = 0;
    long fail_at = -1;   /* the read that fails */
};

static int store_read(void *u, const pb_keyframe_t &k, std::vector<float> *xyz, pb_err_t *err)
{
    Store *st = (Store *)u;
    if (st->reads++ == st->fail_at) return pb_err_set(err, "keyframes.bin: byte %llu: cannot read", (unsigned long long)k.points_key), -1;
    *xyz = st->xyz[(size_t)k.points_key];
    return 0;
}

static void test_points_read_back(const std::vector<Vec3> &world)
{
    std::vector<pb_keyframe_t> kf = make_keyframes(world, 330);
    std::vector<Eigen::Isometry3d> a, b;
    pb_loops_report_t ra, rb;
    pb_err_t err;
    if (CHECK_OK(pb_loops_close(kf, nullptr, &a, &ra, &err), err.msg)) return;
    Store st;
    for (size_t k = 0; k < kf.size(); k++) {
        st.xyz.push_back(kf[k].xyz);
        kf[k].xyz.clear();
        kf[k].points_key = k;
    }
    const pb_keyframe_points_t src = {store_read, &st};
    if (CHECK_OK(pb_loops_close(kf, nullptr, &b, &rb, &err, &src), err.msg)) return;
    bool same = a.size() == b.size() && ra.loops == rb.loops && ra.candidates == rb.candidates;
    for (size_t k = 0; same && k < a.size(); k++) same = a[k].matrix() == b[k].matrix();
    std::printf("points read back: %ld reads for %zu keyframes, %d loops, poses %s\n", st.reads, kf.size(), rb.verified,
                same ? "identical" : "DIFFERENT");
    CHECK(same && rb.verified >= 1);
    st.fail_at = st.reads / 2;   /* fails in the middle of the verifications */
    st.reads = 0;
    CHECK(pb_loops_close(kf, nullptr, &b, &rb, &err, &src) == -1);
    CHECK_CONTAINS(err.msg, "cannot read");
}

int main()
{
    std::vector<Vec3> world = make_world(false);
    test_loop_found_and_closed(world, false);
    test_loop_found_and_closed(world, true);
    test_loop_found_by_place(world);
    test_look_alike_refused(make_world(true));
    test_no_loop_keeps_the_poses(world);
    test_bad_input();
    test_drives_placed(world);
    test_points_read_back(world);
    return pb_check_report("test_mapper_loops");
}
