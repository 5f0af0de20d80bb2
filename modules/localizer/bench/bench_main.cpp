// bench-localizer: time and accuracy of the localizer's scan-to-map registration
// (modules/localizer/core) against PCL's NDT on the same scans and starts.
// small_gicp GICP / VGICP run in bench_gicp.py on the scans this program dumps.
//
// Input: an LCM log with LIDAR_SCAN and GROUND_TRUTH (simdrive, or import-scans of
// real scans), the site's prior map, the vehicle file (base <- lidar).
// Each scan is moved to `base`, deskewed with the ground truth's velocities, and
// aligned from starts made from the ground truth at the scan time (seeded RNG):
//   tracking: N(0, 5 cm) in x, y, N(0, 2 cm) z, N(0, 0.2 deg) yaw, N(0, 0.05 deg) roll/pitch
//   offset:   1 m in a random horizontal direction and +-3 deg yaw
//   global:   (--global R,DEG) uniform within R metres and +-DEG yaw, aligned with
//             pb_reg_align_global (the relocalisation path); --starts K of them per scan
// PCL NDT runs at each resolution of --ndt-res on the same reduced points and starts.
#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#include <pcl/registration/ndt.h>

#include "deskew.h"
#include "pb_arg.h"
#include "pb_clock.h"
#include "pb_err.h"
#include "pb_log.h"
#include "pb_map_build.h"
#include "pb_opt.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"
#include "registration.h"
#include "regmap.h"

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: bench-localizer --log LOG.lcm --map MAP.pcd [--vehicle FILE] [--voxel 0.5]\n"
        "                       [--every N] [--baseline-every K] [--max-scans N] [--odd]\n"
        "                       [--global R,DEG] [--starts K] [--converge M] [--ndt-res R1,R2]\n"
        "                       [--dump FILE] [--json FILE] [--seed N]\n"
        "\n"
        "Aligns every Nth LIDAR_SCAN of LOG (in base, deskewed with GROUND_TRUTH velocities)\n"
        "to MAP from tracking starts and from starts 1 m / 3 deg off, with the localizer's\n"
        "registration, and every Kth of those also with PCL NDT (same voxel, epsilon 1e-4).\n"
        "Prints a table of time per scan and error against GROUND_TRUTH interpolated at\n"
        "the scan time.\n"
        "  --vehicle FILE   base <- lidar (default: the scans are already in base)\n"
        "  --voxel M        map cell / NDT resolution (default 0.5)\n"
        "  --baseline-every K  PCL NDT on every Kth benchmarked scan; 0 = none (default 10)\n"
        "  --odd            only scans with odd index (maps built from the even ones)\n"
        "  --global R,DEG   instead: starts uniform within R m and +-DEG yaw, global align\n"
        "  --starts K       K such starts per scan (default 1)\n"
        "  --converge M     'converged' = final error below M metres (default 0.3)\n"
        "  --ndt-res LIST   PCL NDT resolutions, comma-separated (default: the --voxel)\n"
        "  --dump FILE      write the baseline scans, starts and truth for bench_gicp.py, and the\n"
        "                   map points near them as FILE.map (float32 xyz)\n"
        "  --json FILE      write the per-method results as JSON\n"
        "  --seed N         starts RNG seed (default 1)\n"
        "  --timing-runs N  every tracking align of the subsample (ours reduced, NDT; small_gicp reads it\n"
        "                   from the JSON) is run N times and timed by the median: one scan's single\n"
        "                   millisecond is noise on a shared machine (default 1)\n"
        "  --verbose        one line per scan (ours, tracking start; then each NDT resolution's error)\n"
        "  --target-points N, --coarse-iterations N, --rough-targets 0|1   override the registration defaults\n"
        "\n"
        "       bench-localizer --time-dump DUMP --map MAP.pcd [--global R,DEG] [--timing-runs N]\n"
        "Times ours alone on a --dump file's points and starts (the 'reduced input' rows' work)\n"
        "and prints the CPU ms of each run as JSON, so bench_gicp.py can time ours and small_gicp\n"
        "in turn, round after round, on a machine whose speed wanders.\n");
}

struct Scan {
    int index;
    int64_t utime;
    std::vector<float> pts;         // base frame, deskewed
    Eigen::Isometry3d gt, track_start;
    std::vector<Eigen::Isometry3d> off_starts;
};

static const double kTrackSigma = 0.05;   // m: a tracking start is the truth moved by N(0, this) in x and y
static double g_converge = 0.3;

struct Run {
    std::vector<double> ms, terr, yerr;
    void add(double m, const Eigen::Isometry3d &T, const Eigen::Isometry3d &gt)
    {
        ms.push_back(m);
        terr.push_back((T.translation() - gt.translation()).norm());
        Eigen::Matrix3d D = gt.linear().transpose() * T.linear();
        yerr.push_back(std::fabs(std::atan2(D(1, 0), D(0, 0))) * 180.0 / M_PI);
    }
};

/* CPU ms of one run of fn, as the median of `runs` runs (fn is deterministic: the same
 * work each time) */
template <class F> static double median_ms(long runs, F fn)
{
    std::vector<double> ms;
    for (long i = 0; i < runs; i++) {
        double c0 = pb_clock_thread_cpu_ms();
        fn();
        ms.push_back(pb_clock_thread_cpu_ms() - c0);
    }
    std::nth_element(ms.begin(), ms.begin() + ms.size() / 2, ms.end());
    return ms[ms.size() / 2];
}

static double pct(std::vector<double> v, double p)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    double idx = p / 100.0 * (v.size() - 1);
    size_t lo = (size_t)std::floor(idx), hi = std::min(lo + 1, v.size() - 1);
    return v[lo] + (idx - lo) * (v[hi] - v[lo]);
}

static double share_below(const std::vector<double> &v, double x)
{
    if (v.empty()) return NAN;
    size_t k = 0;
    for (double a : v) k += a < x;
    return (double)k / v.size();
}

static void print_row(const char *method, const char *start, int nscans, const Run &r)
{
    std::printf("| %-26s | %-9s | %5d | %8.2f | %8.2f | %8.3f | %8.3f | %7.3f | %6.1f%% |\n", method, start, nscans,
                pct(r.ms, 50), pct(r.ms, 99), pct(r.terr, 50), pct(r.terr, 99), pct(r.yerr, 99),
                100.0 * share_below(r.terr, g_converge));
}

static void json_run(FILE *f, const char *name, const Run &r, bool last)
{
    if (r.ms.empty()) {   /* a run that did not happen (e.g. --baseline-every 0): no figures, valid JSON */
        std::fprintf(f, "  \"%s\": {\"n\": 0, \"ms_median\": null, \"ms_p99\": null, \"t_median\": null, "
                     "\"t_p99\": null, \"yaw_p99\": null, \"converged\": null}%s\n", name, last ? "" : ",");
        return;
    }
    std::fprintf(f, "  \"%s\": {\"n\": %zu, \"ms_median\": %.4f, \"ms_p99\": %.4f, \"t_median\": %.5f, "
                 "\"t_p99\": %.5f, \"yaw_p99\": %.5f, \"converged\": %.4f,\n", name, r.ms.size(),
                 pct(r.ms, 50), pct(r.ms, 99), pct(r.terr, 50), pct(r.terr, 99), pct(r.yerr, 99),
                 share_below(r.terr, g_converge));
    /* each run's errors, in scan order (a scan's starts together), for figures on a subset */
    auto list = [f](const char *key, const std::vector<double> &v, const char *end) {
        std::fprintf(f, "    \"%s\": [", key);
        for (size_t i = 0; i < v.size(); i++) std::fprintf(f, "%s%.5f", i ? ", " : "", v[i]);
        std::fprintf(f, "]%s\n", end);
    };
    list("errors", r.terr, ",");
    list("yaw_errors", r.yerr, "");
    std::fprintf(f, "  }%s\n", last ? "" : ",");
}

/* What the log gives: the GROUND_TRUTH track and poses (for velocities), the LIDAR_SCAN
 * events as they are (decoded per run). */
struct LogInput {
    pb_pose_track_t *track = pb_pose_track_create();
    std::vector<portobello_pose_t> gts;
    std::vector<std::vector<uint8_t>> raw_scans;

    static void on_pose(const portobello_pose_t *p, const pb_transform_t *T, void *user)
    {
        LogInput *in = (LogInput *)user;
        pb_pose_track_add(in->track, p->utime, T);
        in->gts.push_back(*p);
    }
    static int on_scan(const pb_event_t *ev, void *user, pb_err_t *)
    {
        ((LogInput *)user)->raw_scans.emplace_back(ev->data, ev->data + ev->datalen);
        return 0;
    }
};

/* --global R,DEG: a start searched within R metres and DEG degrees */
static int parse_global(const char *prog, const char *arg, void *var)
{
    double *g = (double *)var;
    if (std::sscanf(arg, "%lf,%lf", &g[0], &g[1]) != 2 || g[0] < 0 || g[1] < 0) {
        std::fprintf(stderr, "%s: --global wants R,DEG, got '%s'\n", prog, arg);
        return -1;
    }
    return 0;
}

/* --ndt-res A,B,...: the NDT resolutions to run */
static int parse_ndt_res(const char *prog, const char *arg, void *var)
{
    std::vector<double> *out = (std::vector<double> *)var;
    std::string list = arg;
    size_t at = 0;
    while (at <= list.size()) {
        size_t e = list.find(',', at);
        std::string item = list.substr(at, e == std::string::npos ? std::string::npos : e - at);
        double r;
        if (pb_arg_double(prog, "ndt-res", item.c_str(), 0.05, 20, &r)) return -1;
        out->push_back(r);
        if (e == std::string::npos) break;
        at = e + 1;
    }
    return 0;
}

/* Our map and the registration's configs (tcfg: a tracking start, which carries the spread
 * it was drawn with, as the localizer's filter gives its own). NULL after a message. */
static pb_regmap_t *load_ours(const char *map_path, double voxel, long target_points, long coarse_iterations,
                              long rough_targets, pb_reg_config_t *rcfg, pb_reg_config_t *tcfg, double *ms_load)
{
    pb_regmap_config_t mcfg;
    pb_regmap_config_default(&mcfg);
    mcfg.voxel_m = voxel;
    pb_err_t err;
    double t0 = pb_clock_thread_cpu_ms();
    pb_regmap_t *map = pb_regmap_load(map_path, &mcfg, nullptr, &err);
    if (!map) { std::fprintf(stderr, "bench-localizer: %s\n", err.msg); return nullptr; }
    *ms_load = pb_clock_thread_cpu_ms() - t0;
    pb_reg_config_default(rcfg);
    if (target_points >= 0) rcfg->target_points = (int)target_points;
    if (coarse_iterations >= 0) rcfg->coarse_iterations = (int)coarse_iterations;
    if (rough_targets >= 0) rcfg->rough_targets = (int)rough_targets;
    *tcfg = *rcfg;
    tcfg->prior_sigma_m = kTrackSigma;
    return map;
}

/* How an offset start is aligned: searched (--global R,DEG) or aligned from where it is. */
struct OffSearch {
    bool global;
    double radius_m, yaw_rad;
};

/* Ours from one offset start, timed: CPU ms of this thread. */
static double align_off(const pb_regmap_t *map, const float *pts, size_t n, const Eigen::Isometry3d &start,
                        const OffSearch &how, const pb_reg_config_t &cfg, pb_reg_result_t *r)
{
    pb_err_t err;
    double c0 = pb_clock_thread_cpu_ms();
    if (how.global) pb_reg_align_global(map, pts, n, start, how.radius_m, how.yaw_rad, &cfg, r, &err);
    else pb_reg_align(map, pts, n, start, &cfg, r, &err);
    return pb_clock_thread_cpu_ms() - c0;
}

/* --time-dump: ours on the dumped reduced points and starts, as the 'reduced input' rows
 * run them: {"track_ms": [one per scan, median of timing_runs], "off_ms": [one per start]} */
static int time_dump(const char *dump, const pb_regmap_t *map, const pb_reg_config_t &rcfg, const pb_reg_config_t &tcfg,
                     const OffSearch &how, long timing_runs)
{
    FILE *f = std::fopen(dump, "rb");
    if (!f) { std::fprintf(stderr, "bench-localizer: %s: %s\n", dump, std::strerror(errno)); return 1; }
    std::vector<double> track_ms, off_ms;
    pb_reg_result_t r;
    pb_err_t err;
    long scan = 0;
    for (int32_t n; std::fread(&n, 4, 1, f) == 1; scan++) {
        std::vector<float> pts(3 * (size_t)std::max(n, 0));
        int32_t ns = -1;
        bool ok = n > 0 && std::fread(pts.data(), 4, pts.size(), f) == pts.size() && std::fread(&ns, 4, 1, f) == 1 && ns >= 0;
        std::vector<Eigen::Isometry3d> mats;
        for (int32_t k = 0; ok && k < 2 + ns; k++) {
            Eigen::Matrix<double, 4, 4, Eigen::RowMajor> M;
            ok = std::fread(M.data(), 8, 16, f) == 16;
            mats.push_back(Eigen::Isometry3d(Eigen::Matrix4d(M)));
        }
        if (!ok) {
            std::fprintf(stderr, "bench-localizer: %s: scan %ld (byte %ld) is cut short or malformed\n", dump, scan, std::ftell(f));
            std::fclose(f);
            return 1;
        }
        track_ms.push_back(median_ms(timing_runs, [&] { pb_reg_align(map, pts.data(), (size_t)n, mats[1], &tcfg, &r, &err); }));
        for (int32_t k = 0; k < ns; k++) off_ms.push_back(align_off(map, pts.data(), (size_t)n, mats[2 + k], how, rcfg, &r));
    }
    std::fclose(f);
    auto list = [](const std::vector<double> &v) {
        std::string s;
        for (double x : v) s += (s.empty() ? "" : ", ") + std::to_string(x);
        return s;
    };
    std::printf("{\"track_ms\": [%s], \"off_ms\": [%s]}\n", list(track_ms).c_str(), list(off_ms).c_str());
    return 0;
}

int main(int argc, char **argv)
{
    const char *log_path = nullptr, *map_path = nullptr, *vehicle_path = nullptr, *dump = nullptr, *json = nullptr,
               *time_dump_path = nullptr;
    double voxel = 0.5, global_search[2] = { -1, -1 };   /* radius, yaw (deg); < 0: no --global */
    long every = 1, base_every = 10, max_scans = 1000000, seed = 1, nstarts = 1, timing_runs = 1;
    std::vector<double> ndt_res;
    bool odd = false, verbose = false;
    long target_points = -1, coarse_iterations = -1, rough_targets = -1;
    const pb_opt_t opts[] = {
        PB_OPT_STRING("log", &log_path), PB_OPT_REQUIRED("map", &map_path), PB_OPT_STRING("time-dump", &time_dump_path), PB_OPT_STRING("vehicle", &vehicle_path),
        PB_OPT_DOUBLE("voxel", &voxel, 0.05, 10), PB_OPT_LONG("every", &every, 1, 100000),
        PB_OPT_LONG("baseline-every", &base_every, 0, 100000), PB_OPT_LONG("max-scans", &max_scans, 1, 100000000),
        PB_OPT_BOOL("odd", &odd, 1), PB_OPT_CALL("global", parse_global, global_search), PB_OPT_STRING("dump", &dump),
        PB_OPT_STRING("json", &json), PB_OPT_LONG("seed", &seed, 0, 1L << 40), PB_OPT_BOOL("verbose", &verbose, 1),
        PB_OPT_LONG("starts", &nstarts, 1, 10000), PB_OPT_DOUBLE("converge", &g_converge, 0.001, 100),
        PB_OPT_CALL("ndt-res", parse_ndt_res, &ndt_res), PB_OPT_LONG("target-points", &target_points, 0, 1000000),
        PB_OPT_LONG("coarse-iterations", &coarse_iterations, 0, 100), PB_OPT_LONG("rough-targets", &rough_targets, 0, 1),
        PB_OPT_LONG("timing-runs", &timing_runs, 1, 1000), PB_OPT_END,
    };
    int parsed = pb_opt_parse("bench-localizer", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    const bool global = global_search[0] >= 0;
    const double g_radius = global_search[0], g_yaw_deg = global_search[1];
    if (!log_path == !time_dump_path) {
        std::fprintf(stderr, "bench-localizer: give one of --log (a benchmark run) and --time-dump (ours timed on a dump)\n");
        return 2;
    }
    if (ndt_res.empty()) ndt_res.push_back(voxel);
    if (!global) nstarts = 1;
    if (time_dump_path) {
        double ms_load;
        pb_reg_config_t rcfg, tcfg;
        pb_regmap_t *map = load_ours(map_path, voxel, target_points, coarse_iterations, rough_targets, &rcfg, &tcfg, &ms_load);
        if (!map) return 1;
        int rc = time_dump(time_dump_path, map, rcfg, tcfg, { global, g_radius, g_yaw_deg * M_PI / 180 }, timing_runs);
        pb_regmap_destroy(map);
        return rc;
    }
    pb_err_t err;
    pb_transform_t base_from_lidar = {{0, 0, 0}, {1, 0, 0, 0}};
    if (vehicle_path) {
        pb_vehicle_t veh;
        if (pb_vehicle_load(vehicle_path, &veh, &err)) { std::fprintf(stderr, "bench-localizer: %s\n", err.msg); return 1; }
        base_from_lidar = veh.base_from_lidar;
    }
    const Eigen::Isometry3d B = pb_reg_from_transform(&base_from_lidar);

    // ---- read the log: ground truth track (+ velocities), then scans
    LogInput in;
    if (pb_log_read_track(log_path, "GROUND_TRUTH", LogInput::on_pose, "LIDAR_SCAN", LogInput::on_scan, &in, &err)) {
        std::fprintf(stderr, "bench-localizer: %s\n", err.msg);
        return 1;
    }
    pb_pose_track_t *track = in.track;
    std::vector<portobello_pose_t> &gts = in.gts;
    std::vector<std::vector<uint8_t>> &raw_scans = in.raw_scans;
    std::sort(gts.begin(), gts.end(), [](const portobello_pose_t &a, const portobello_pose_t &b) { return a.utime < b.utime; });

    std::mt19937_64 rng((uint64_t)seed);
    std::normal_distribution<double> nrm(0.0, 1.0);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    auto perturb = [](const Eigen::Isometry3d &T, double dx, double dy, double dz, double rr, double rp, double ry) {
        Eigen::Isometry3d P = T;
        P.translation() += Eigen::Vector3d(dx, dy, dz);
        P.linear() = (Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rp, Eigen::Vector3d::UnitY()) *
                      Eigen::AngleAxisd(rr, Eigen::Vector3d::UnitX())).toRotationMatrix() * T.linear();
        return P;
    };
    const double deg = M_PI / 180.0;
    std::vector<Scan> scans;
    pb_points_t pts = {};
    double ms_prep = 0;
    int raw_points_max = 0;
    for (size_t k = 0; k < raw_scans.size() && (long)scans.size() < max_scans; k++) {
        if (odd && k % 2 == 0) continue;
        if ((long)((odd ? k / 2 : k) % every) != 0) continue;
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(raw_scans[k].data(), 0, (int)raw_scans[k].size(), &s) < 0) continue;
        int64_t ut = s.utime;
        int np = pb_scan_points(&s, &pts, &err);
        portobello_lidar_scan_t_decode_cleanup(&s);
        if (np <= 0) continue;
        pb_transform_t gt_t;
        if (!pb_pose_track_at(track, ut, &gt_t)) continue;   // outside the truth
        // nearest truth sample for the velocities (100 Hz; constant over a sweep)
        auto it = std::lower_bound(gts.begin(), gts.end(), ut, [](const portobello_pose_t &p, int64_t t) { return p.utime < t; });
        if (it == gts.end()) continue;
        Scan sc;
        sc.index = (int)k;
        sc.utime = ut;
        sc.gt = pb_reg_from_transform(&gt_t);
        double t0 = pb_clock_thread_cpu_ms();
        sc.pts.resize(3 * (size_t)np);
        for (int i = 0; i < np; i++) {
            Eigen::Vector3d p = B * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
            for (int a = 0; a < 3; a++) sc.pts[3 * i + a] = (float)p(a);
        }
        Eigen::Vector3d v_base = sc.gt.linear().transpose() * Eigen::Vector3d(it->velocity[0], it->velocity[1], it->velocity[2]);
        pb_deskew(sc.pts.data(), pts.offset_us, (size_t)np, 0, v_base.data(), it->angular_velocity);
        ms_prep += pb_clock_thread_cpu_ms() - t0;
        raw_points_max = std::max(raw_points_max, np);
        if (global) {
            for (long k = 0; k < nstarts; k++) {
                double r = g_radius * std::sqrt(uni(rng)), a = 2 * M_PI * uni(rng), y = (2 * uni(rng) - 1) * g_yaw_deg * deg;
                sc.off_starts.push_back(perturb(sc.gt, r * std::cos(a), r * std::sin(a), 0, 0, 0, y));
            }
            sc.track_start = perturb(sc.gt, kTrackSigma * nrm(rng), kTrackSigma * nrm(rng), 0.02 * nrm(rng), 0.05 * deg * nrm(rng),
                                     0.05 * deg * nrm(rng), 0.2 * deg * nrm(rng));
        } else {
            sc.track_start = perturb(sc.gt, kTrackSigma * nrm(rng), kTrackSigma * nrm(rng), 0.02 * nrm(rng), 0.05 * deg * nrm(rng),
                                     0.05 * deg * nrm(rng), 0.2 * deg * nrm(rng));
            double a = 2 * M_PI * uni(rng);
            sc.off_starts.push_back(perturb(sc.gt, std::cos(a), std::sin(a), 0, 0, 0, (uni(rng) < 0.5 ? -3 : 3) * deg));
        }
        scans.push_back(std::move(sc));
    }
    pb_points_free(&pts);
    raw_scans.clear();
    if (scans.empty()) { std::fprintf(stderr, "bench-localizer: %s: no LIDAR_SCAN within GROUND_TRUTH\n", log_path); return 1; }

    // ---- our registration: map prepared once, then every scan
    double ms_load = 0;
    pb_reg_config_t rcfg, tcfg;
    pb_regmap_t *map = load_ours(map_path, voxel, target_points, coarse_iterations, rough_targets, &rcfg, &tcfg, &ms_load);
    if (!map) return 1;
    pb_regmap_info_t info;
    pb_regmap_info(map, &info);
    const OffSearch off_search = { global, g_radius, g_yaw_deg * deg };
    Run ours_track, ours_off, ours_track_sub, ours_off_sub, ours_track_red, ours_off_red;
    std::vector<std::vector<float>> reduced(scans.size());
    for (size_t k = 0; k < scans.size(); k++) {
        const Scan &sc = scans[k];
        bool sub = base_every > 0 && k % (size_t)base_every == 0;
        pb_reg_result_t r;
        {
            double c0 = pb_clock_thread_cpu_ms();
            pb_reg_align(map, sc.pts.data(), sc.pts.size() / 3, sc.track_start, &tcfg, &r, &err);
            double ms = pb_clock_thread_cpu_ms() - c0;
            ours_track.add(ms, r.pose, sc.gt);
            if (verbose) {
                // the same scores at the reference pose itself: which pose fits the map better?
                pb_reg_config_t ev = rcfg;
                ev.max_iterations = 0;
                ev.coarse_iterations = 0;
                pb_reg_result_t at_gt;
                pb_reg_align(map, sc.pts.data(), sc.pts.size() / 3, sc.gt, &ev, &at_gt, &err);
                std::printf("scan %d tracking: err %.3f m, status %d, it %d, pts %d, inl %.3f (at reference %.3f), "
                            "upright %.3f (at reference %.3f, %d pts), rmse %.3f, cond %.3g, sd x %.3f y %.3f yaw %.3f deg\n",
                            sc.index, ours_track.terr.back(), r.status, r.iterations, r.points_used, r.inlier_fraction,
                            at_gt.inlier_fraction, r.upright_inlier_fraction, at_gt.upright_inlier_fraction,
                            r.upright_points, r.rmse_m, r.condition, std::sqrt(r.covariance(0, 0)),
                            std::sqrt(r.covariance(1, 1)), std::sqrt(r.covariance(5, 5)) / deg);
            }
            if (sub) ours_track_sub.add(ms, r.pose, sc.gt);
            size_t off0 = ours_off.terr.size();
            std::vector<double> off_inl;
            for (const Eigen::Isometry3d &start : sc.off_starts) {
                ms = align_off(map, sc.pts.data(), sc.pts.size() / 3, start, off_search, rcfg, &r);
                ours_off.add(ms, r.pose, sc.gt);
                off_inl.push_back(r.inlier_fraction);
                if (sub) ours_off_sub.add(ms, r.pose, sc.gt);
            }
            if (verbose && !sc.off_starts.empty()) {
                // do the failures of a scan's starts cluster (the scan) or scatter (the search)?
                int ok = 0;
                std::string errs;
                for (size_t i = off0; i < ours_off.terr.size(); i++) {
                    ok += ours_off.terr[i] < g_converge;
                    char b[32];
                    std::snprintf(b, sizeof b, " %.2f (%.3f)", ours_off.terr[i], off_inl[i - off0]);
                    errs += b;
                }
                std::printf("scan %d off starts: %d/%zu within %.2f m; errors (inliers)%s\n", sc.index, ok, sc.off_starts.size(),
                            g_converge, errs.c_str());
            }
        }
        if (sub) {
            // the same reduced points the baselines get, through our whole call again
            pb_reg_downsample(sc.pts.data(), sc.pts.size() / 3, &rcfg, &reduced[k]);
            const std::vector<float> &rp = reduced[k];
            for (const Eigen::Isometry3d &start : sc.off_starts)
                ours_off_red.add(align_off(map, rp.data(), rp.size() / 3, start, off_search, rcfg, &r), r.pose, sc.gt);
            double ms = median_ms(timing_runs, [&] { pb_reg_align(map, rp.data(), rp.size() / 3, sc.track_start, &tcfg, &r, &err); });
            ours_track_red.add(ms, r.pose, sc.gt);
        }
    }
    pb_regmap_destroy(map);

    // ---- baselines on the subsample: the same reduced points (our downsampling,
    // range filter included) and the same starts; the map cropped to 120 m of them
    std::vector<Run> ndt_track(ndt_res.size()), ndt_off(ndt_res.size());
    std::vector<double> ms_ndt_target(ndt_res.size(), 0);
    size_t nsub = 0, map_crop = 0;
    if (base_every > 0) {
        pcl::PointCloud<pcl::PointXYZ>::Ptr full(new pcl::PointCloud<pcl::PointXYZ>), crop(new pcl::PointCloud<pcl::PointXYZ>);
        if (pcl::io::loadPCDFile(map_path, *full) < 0) { std::fprintf(stderr, "bench-localizer: %s: cannot read\n", map_path); return 1; }
        std::vector<Eigen::Vector2d> centres;
        for (size_t k = 0; k < scans.size(); k += (size_t)base_every) centres.push_back(scans[k].gt.translation().head<2>());
        for (const auto &p : full->points) {
            for (const auto &c2 : centres)
                if ((Eigen::Vector2d(p.x, p.y) - c2).squaredNorm() < 120.0 * 120.0) { crop->push_back(p); break; }
        }
        full.reset();
        map_crop = crop->size();
        FILE *df = nullptr;
        if (dump) {
            df = std::fopen(dump, "wb");
            std::string mp = std::string(dump) + ".map";
            FILE *mf = std::fopen(mp.c_str(), "wb");
            if (!df || !mf) { std::fprintf(stderr, "bench-localizer: %s: cannot write\n", dump); return 1; }
            for (const auto &p : crop->points) { float v[3] = {p.x, p.y, p.z}; std::fwrite(v, 4, 3, mf); }
            std::fclose(mf);
        }
        for (size_t ri = 0; ri < ndt_res.size(); ri++) {
            pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ> ndt;
            ndt.setResolution((float)ndt_res[ri]);
            ndt.setTransformationEpsilon(1e-4);   // PCL 1.13 compares it with the squared step
            ndt.setStepSize(0.1);
            ndt.setMaximumIterations(35);
            double t0 = pb_clock_thread_cpu_ms();
            ndt.setInputTarget(crop);
            ms_ndt_target[ri] = pb_clock_thread_cpu_ms() - t0;
            for (size_t k = 0; k < scans.size(); k += (size_t)base_every) {
                const Scan &sc = scans[k];
                pcl::PointCloud<pcl::PointXYZ>::Ptr src(new pcl::PointCloud<pcl::PointXYZ>);
                for (size_t i = 0; i + 2 < reduced[k].size(); i += 3)
                    src->push_back(pcl::PointXYZ(reduced[k][i], reduced[k][i + 1], reduced[k][i + 2]));
                ndt.setInputSource(src);
                pcl::PointCloud<pcl::PointXYZ> out;
                auto run = [&](const Eigen::Isometry3d &start, long runs, Run *into) {
                    double ms = median_ms(runs, [&] { ndt.align(out, start.matrix().cast<float>()); });
                    into->add(ms, Eigen::Isometry3d(ndt.getFinalTransformation().cast<double>()), sc.gt);
                };
                run(sc.track_start, timing_runs, &ndt_track[ri]);
                if (verbose) std::printf("scan %d tracking: NDT %.1f m err %.3f m\n", sc.index, ndt_res[ri], ndt_track[ri].terr.back());
                for (const Eigen::Isometry3d &start : sc.off_starts) run(start, 1, &ndt_off[ri]);
                if (ri == 0 && df) {
                    // per scan: n, points, number of starts, then truth, tracking start, each start (row-major 4x4)
                    int32_t n = (int32_t)(reduced[k].size() / 3), ns = (int32_t)sc.off_starts.size();
                    std::fwrite(&n, 4, 1, df);
                    std::fwrite(reduced[k].data(), 4, reduced[k].size(), df);
                    std::fwrite(&ns, 4, 1, df);
                    std::vector<const Eigen::Isometry3d *> mats = {&sc.gt, &sc.track_start};
                    for (const auto &st : sc.off_starts) mats.push_back(&st);
                    for (auto *m : mats) {
                        Eigen::Matrix<double, 4, 4, Eigen::RowMajor> M = m->matrix();
                        std::fwrite(M.data(), 8, 16, df);
                    }
                }
                if (ri == 0) nsub++;
            }
        }
        if (df) std::fclose(df);
    }

    // ---- table
    std::printf("bench-localizer: %s, %zu scans (every %ld%s, up to %d points each, %.2f ms/scan to base + deskew)\n",
                log_path, scans.size(), every, odd ? ", odd only" : "", raw_points_max, ms_prep / scans.size());
    std::printf("map %s: %lld points -> %lld cells of %.2f m (%lld planes), prepared in %.0f ms\n", map_path,
                (long long)info.points, (long long)info.cells, voxel, (long long)info.planar_cells, ms_load);
    if (base_every > 0)
        std::printf("'subsample' rows: the scans the baselines run on, raw scan in (our downsampling timed); 'reduced\n"
                    "input' rows: every method gets the same already reduced points (%d target points) and starts\n",
                    rcfg.target_points);
    std::printf("ms: CPU time of the aligning thread per scan (one core); err: |translation - truth| m; "
                "yaw p99: deg; conv: share of runs ending within %.2f m; %ld start(s) per scan besides tracking\n",
                g_converge, nstarts);
    if (base_every > 0)
        std::printf("baselines on every %ld-th benchmarked scan (%zu scans), map cropped to 120 m of them "
                    "(%zu points; NDT target built in %.0f ms at %.2f m)\n", base_every, nsub, map_crop,
                    ms_ndt_target[0], ndt_res[0]);
    std::printf("\n| %-26s | %-9s | %5s | %8s | %8s | %8s | %8s | %7s | %7s |\n", "method", "start", "runs",
                "ms med", "ms p99", "err med", "err p99", "yaw p99", "conv");
    std::printf("|%s|%s|%s|%s|%s|%s|%s|%s|%s|\n", std::string(28, '-').c_str(), std::string(11, '-').c_str(),
                std::string(7, '-').c_str(), std::string(10, '-').c_str(), std::string(10, '-').c_str(),
                std::string(10, '-').c_str(), std::string(10, '-').c_str(), std::string(9, '-').c_str(),
                std::string(9, '-').c_str());
    char start[32];
    if (global) std::snprintf(start, sizeof start, "%.0fm/%.0fdeg", g_radius, g_yaw_deg);
    else std::snprintf(start, sizeof start, "1m/3deg");
    const char *how = global ? "ours (global align)" : "ours";
    print_row("ours", "tracking", (int)ours_track.ms.size(), ours_track);
    print_row(how, start, (int)ours_off.ms.size(), ours_off);
    if (nsub) {
        print_row("ours, subsample", "tracking", (int)ours_track_sub.ms.size(), ours_track_sub);
        print_row("ours, subsample", start, (int)ours_off_sub.ms.size(), ours_off_sub);
        print_row("ours, reduced input", "tracking", (int)ours_track_red.ms.size(), ours_track_red);
        print_row("ours, reduced input", start, (int)ours_off_red.ms.size(), ours_off_red);
        for (size_t ri = 0; ri < ndt_res.size(); ri++) {
            char name[64];
            std::snprintf(name, sizeof name, "PCL NDT %.1f m, reduced", ndt_res[ri]);
            print_row(name, "tracking", (int)ndt_track[ri].ms.size(), ndt_track[ri]);
            print_row(name, start, (int)ndt_off[ri].ms.size(), ndt_off[ri]);
        }
    }
    if (json) {
        FILE *f = std::fopen(json, "w");
        if (!f) { std::fprintf(stderr, "bench-localizer: %s: cannot write\n", json); return 1; }
        /* what bench_gicp.py needs to time ours again on the dump (--time-dump) */
        char map_abs[PATH_MAX];
        if (!realpath(map_path, map_abs)) std::snprintf(map_abs, sizeof map_abs, "%s", map_path);
        std::fprintf(f, "{\n  \"map\": \"%s\", \"voxel\": %g, \"global_radius_m\": %g, \"global_yaw_deg\": %g, "
                     "\"target_points\": %ld, \"coarse_iterations\": %ld, \"rough_targets\": %ld,\n", map_abs, voxel,
                     g_radius, g_yaw_deg, target_points, coarse_iterations, rough_targets);
        std::fprintf(f, "  \"scans\": %zu, \"baseline_scans\": %zu, \"baseline_every\": %ld, \"global\": %s,\n"
                     "  \"starts_per_scan\": %ld, \"timing_runs\": %ld, \"converge_m\": %g, \"start\": \"%s\", \"ndt_res\": [",
                     scans.size(), nsub, base_every, global ? "true" : "false", nstarts, timing_runs, g_converge, start);
        for (size_t ri = 0; ri < ndt_res.size(); ri++) std::fprintf(f, "%s%g", ri ? ", " : "", ndt_res[ri]);
        /* which log scans (LIDAR_SCAN k of the log) the runs are of: every benchmarked scan, the baselines' */
        auto indices = [&](const char *key, long step) {
            std::fprintf(f, "],\n  \"%s\": [", key);
            for (size_t k = 0; step > 0 && k < scans.size(); k += (size_t)step) std::fprintf(f, "%s%d", k ? ", " : "", scans[k].index);
        };
        indices("scan_index", 1);
        indices("baseline_scan_index", base_every);
        std::fprintf(f, "],\n");
        json_run(f, "ours_track", ours_track, false);
        json_run(f, "ours_off", ours_off, false);
        json_run(f, "ours_track_sub", ours_track_sub, false);
        json_run(f, "ours_off_sub", ours_off_sub, false);
        json_run(f, "ours_track_red", ours_track_red, false);
        for (size_t ri = 0; ri < ndt_res.size(); ri++) {
            char name[64];
            std::snprintf(name, sizeof name, "ndt%g_track", ndt_res[ri]);
            json_run(f, name, ndt_track[ri], false);
            std::snprintf(name, sizeof name, "ndt%g_off", ndt_res[ri]);
            json_run(f, name, ndt_off[ri], false);
        }
        json_run(f, "ours_off_red", ours_off_red, true);
        std::fprintf(f, "}\n");
        std::fclose(f);
    }
    pb_pose_track_destroy(track);
    return 0;
}
