// refine-poses: multi-scan refinement of the poses of a LiDAR sequence
// (modules/localizer/core/refine.h): a better reference than a SLAM estimate,
// with a report of how self-consistent the result is.
//
// Input: an import-scans log (LIDAR_SCAN in point form + GROUND_TRUTH, the LiDAR
// pose, at the same utime). Output: the refined LiDAR poses, one KITTI line
// (3x4 row-major) per scan in log order, readable by import-scans --poses.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "pb_err.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"
#include "refine.h"
#include "registration.h"

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: refine-poses --log SCANS.lcm --out POSES.txt [--report REPORT.json] [--rounds 8]\n"
        "                    [--radius 40] [--neighbours 30] [--quiet]\n"
        "\n"
        "Refines the poses of a LiDAR sequence so its scans agree with each other: each round\n"
        "registers every scan to a map of the other scans near it (itself left out) with the\n"
        "localizer's registration, moves all scans at once, and keeps the input's frame (the\n"
        "rigid motion that best aligns the result with the input is removed). SCANS.lcm is an\n"
        "import-scans log (LIDAR_SCAN point form, GROUND_TRUTH = LiDAR pose at the same utime).\n"
        "Writes one KITTI line (3x4 row-major, map <- LiDAR) per scan, for import-scans --poses,\n"
        "and prints how consistent the poses are before and after: leave-one-out moves (how far\n"
        "each scan would still move given all the others) and the fit of each scan to the map of\n"
        "the others (share of points within 0.1 m of a surface).\n"
        "  --report FILE    the same figures and per-scan values as JSON\n"
        "  --rounds N       at most N rounds (default 8; stops when no scan moves 5 mm)\n"
        "  --radius M       scans within M metres form a scan's map (default 40)\n"
        "  --neighbours N   at most the N nearest (default 30)\n");
}

static double pct(std::vector<double> v, double p)
{
    v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }), v.end());
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    double idx = p / 100.0 * (v.size() - 1);
    size_t lo = (size_t)std::floor(idx), hi = std::min(lo + 1, v.size() - 1);
    return v[lo] + (idx - lo) * (v[hi] - v[lo]);
}

static void progress(int round, double moved, void *user)
{
    if (!*(bool *)user) std::fprintf(stderr, "refine-poses: round %d: largest move %.3f m\n", round, moved);
}

static void json_array(FILE *f, const char *name, const std::vector<double> &v, bool last)
{
    std::fprintf(f, "  \"%s\": [", name);
    for (size_t i = 0; i < v.size(); i++) std::fprintf(f, "%s%.5g", i ? ", " : "", std::isfinite(v[i]) ? v[i] : -1.0);
    std::fprintf(f, "]%s\n", last ? "" : ",");
}

/* What the log gives: GROUND_TRUTH by utime, and each LIDAR_SCAN's points with its utime. */
struct LogInput {
    std::map<int64_t, Eigen::Isometry3d> truth;
    std::vector<std::pair<int64_t, std::vector<float>>> raw;
    pb_points_t pts = {};

    static void on_pose(const portobello_pose_t *p, const pb_transform_t *T, void *user)
    {
        ((LogInput *)user)->truth[p->utime] = pb_reg_from_transform(T);
    }
    static int on_scan(const pb_event_t *ev, void *user, pb_err_t *err)
    {
        LogInput *in = (LogInput *)user;
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(ev->data, 0, ev->datalen, &s) < 0)
            return pb_err_set(err, "LIDAR_SCAN at byte %lld does not decode", (long long)ev->offset);
        int n = pb_scan_points(&s, &in->pts, err);
        int64_t ut = s.utime;
        portobello_lidar_scan_t_decode_cleanup(&s);
        if (n < 0) return -1;
        std::vector<float> xyz(3 * (size_t)n);
        for (int i = 0; i < n; i++) { xyz[3 * i] = in->pts.x[i]; xyz[3 * i + 1] = in->pts.y[i]; xyz[3 * i + 2] = in->pts.z[i]; }
        in->raw.emplace_back(ut, std::move(xyz));
        return 0;
    }
};

int main(int argc, char **argv)
{
    const char *log_path = nullptr, *out_path = nullptr, *report_path = nullptr;
    pb_refine_config_t cfg;
    pb_refine_config_default(&cfg);
    bool quiet = false;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &log_path), PB_OPT_REQUIRED("out", &out_path), PB_OPT_STRING("report", &report_path),
        PB_OPT_INT("rounds", &cfg.max_rounds, 1, 100), PB_OPT_DOUBLE("radius", &cfg.neighbour_radius_m, 1, 1000),
        PB_OPT_INT("neighbours", &cfg.max_neighbours, 1, 1000), PB_OPT_BOOL("quiet", &quiet, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("refine-poses", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    LogInput in;
    int rc = pb_log_read_track(log_path, "GROUND_TRUTH", LogInput::on_pose, "LIDAR_SCAN", LogInput::on_scan, &in, &err);
    pb_points_free(&in.pts);
    if (rc) { std::fprintf(stderr, "refine-poses: %s\n", err.msg); return 1; }
    std::vector<std::vector<float>> scans;
    std::vector<Eigen::Isometry3d> poses;
    for (auto &r : in.raw) {
        auto it = in.truth.find(r.first);
        if (it == in.truth.end()) {
            std::fprintf(stderr, "refine-poses: %s: LIDAR_SCAN at utime %lld has no GROUND_TRUTH at the same utime "
                         "(an import-scans log is expected)\n", log_path, (long long)r.first);
            return 1;
        }
        scans.push_back(std::move(r.second));
        poses.push_back(it->second);
    }
    pb_refine_report_t rep;
    if (pb_refine_poses(scans, &poses, &cfg, &rep, progress, &quiet, &err) != 0) {
        std::fprintf(stderr, "refine-poses: %s: %s\n", log_path, err.msg);
        return 1;
    }
    FILE *f = std::fopen(out_path, "w");
    if (!f) { std::fprintf(stderr, "refine-poses: %s: cannot write\n", out_path); return 1; }
    for (const auto &T : poses) {
        const Eigen::Matrix<double, 3, 4> M = T.matrix().topRows<3>();
        for (int r = 0; r < 3; r++)
            for (int k = 0; k < 4; k++) std::fprintf(f, "%.9g%s", M(r, k), r == 2 && k == 3 ? "\n" : " ");
    }
    if (std::fclose(f) != 0) { std::fprintf(stderr, "refine-poses: %s: cannot write\n", out_path); return 1; }
    if (!quiet) {
        std::printf("refine-poses: %zu scans, %d rounds (largest move in the last %.4f m), %d kept their pose\n",
                    poses.size(), rep.rounds, rep.moved_m.back(), rep.kept);
        std::printf("  fit to the others (share within 0.1 m): input median %.3f p10 %.3f -> refined median %.3f p10 %.3f\n",
                    pct(rep.fit_before, 50), pct(rep.fit_before, 10), pct(rep.fit_after, 50), pct(rep.fit_after, 10));
        std::printf("  leave-one-out move after refinement: median %.3f m p90 %.3f m max %.3f m, %.3f / %.3f deg (median / p90)\n",
                    pct(rep.loo_m, 50), pct(rep.loo_m, 90), pct(rep.loo_m, 100), pct(rep.loo_deg, 50), pct(rep.loo_deg, 90));
        std::printf("  refined minus input position: median %.3f m p90 %.3f m max %.3f m\n", pct(rep.change_m, 50),
                    pct(rep.change_m, 90), pct(rep.change_m, 100));
    }
    if (report_path) {
        FILE *jf = std::fopen(report_path, "w");
        if (!jf) { std::fprintf(stderr, "refine-poses: %s: cannot write\n", report_path); return 1; }
        std::fprintf(jf, "{\n  \"scans\": %zu, \"rounds\": %d, \"kept\": %d,\n", poses.size(), rep.rounds, rep.kept);
        std::fprintf(jf, "  \"fit_before_median\": %.4f, \"fit_after_median\": %.4f, \"loo_m_median\": %.4f, "
                     "\"loo_m_p90\": %.4f, \"loo_m_max\": %.4f, \"loo_deg_median\": %.4f, \"change_m_median\": %.4f,\n",
                     pct(rep.fit_before, 50), pct(rep.fit_after, 50), pct(rep.loo_m, 50), pct(rep.loo_m, 90),
                     pct(rep.loo_m, 100), pct(rep.loo_deg, 50), pct(rep.change_m, 50));
        json_array(jf, "moved_m", rep.moved_m, false);
        json_array(jf, "fit_before", rep.fit_before, false);
        json_array(jf, "fit_after", rep.fit_after, false);
        json_array(jf, "loo_m", rep.loo_m, false);
        json_array(jf, "change_m", rep.change_m, true);
        std::fprintf(jf, "}\n");
        std::fclose(jf);
    }
    return 0;
}
