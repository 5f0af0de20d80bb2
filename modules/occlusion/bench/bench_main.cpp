/* occlusion-bench: the cost of the occlusion pipeline and of stock OctoMap on the same
 * sweeps and queries (one thread; CPU time of the thread, so other load on the machine
 * does not count).
 *   occlusion-bench --log DRIVE.lcm --out OUT.lcm [--stock-from N] [--stock-count M]
 * For every sweep of DRIVE (simdrive with --scenario): ours integrates it (timed) and
 * queries 100 agents (the scene's agents in range, repeated to 100; timed). For sweeps
 * N .. N+M-1 (after N-10 untimed warm-up sweeps) stock OctoMap insertPointCloud takes
 * the same points (in range, map frame, from the sweep's mid sensor origin; timed) and
 * castRay answers the same queries (timed): OUT gets OCCLUSION (ours) and
 * OCCLUSION_STOCK for those sweeps, so one agreement script scores both.
 * Prints one JSON object of timings on stdout. */
#include <sys/resource.h>
#include <time.h>

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "core/occlusion.h"
#include "occ_message.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "portobello_agents_t.h"
#include "pb_clock.h"
#include "portobello_head_pose_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_occlusion_t.h"
#include "portobello_pose_t.h"

/* Resident memory of this process, kB (Linux /proc/self/statm). */
static long rss_kb()
{
    FILE *f = fopen("/proc/self/statm", "r");
    long pages = 0, res = 0;
    if (f) { if (fscanf(f, "%ld %ld", &pages, &res) != 2) res = 0; fclose(f); }
    return res * 4;
}

static double pct(std::vector<double> v, double q)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return v[(size_t)std::min<double>(v.size() - 1, std::ceil(q * v.size()) - 1)];
}

static void write_occ(pb_log_out_t *o, const char *ch, const occ_output_t &r)
{
    std::vector<portobello_agent_occlusion_t> ag;
    portobello_occlusion_t m = occ_message(r, &ag);
    int n = portobello_occlusion_t_encoded_size(&m);
    std::vector<uint8_t> buf(n);
    portobello_occlusion_t_encode(buf.data(), 0, n, &m);
    if (!o->failed && pb_log_write(o->log, m.utime, ch, buf.data(), n, &o->err)) o->failed = 1;
}

/* Stock OctoMap's answer for one sample: castRay from where the eye ray leaves the car
 * (as ours: the eye looks out through the car, which the LiDAR never sees inside);
 * ground voxels (centre below ground + clearance) are passed through, as ours ignores
 * ground returns. */
static int8_t stock_query(const octomap::OcTree &tree, const occ_config_t &c, const double eye[3], double t0, double ground_z,
                          double sx, double sy, double sz, float *occ)
{
    *occ = NAN;
    double d[3] = { sx - eye[0], sy - eye[1], sz - eye[2] };
    double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (len > c.range_m) return OCC_UNKNOWN;
    double tend = len - c.stop_short_m;
    if (t0 >= tend) return OCC_VISIBLE;
    octomap::point3d dir((float)(d[0] / len), (float)(d[1] / len), (float)(d[2] / len));
    double t = t0;
    for (int guard = 0; guard < 1000; guard++) {
        octomap::point3d o((float)(eye[0] + dir.x() * t), (float)(eye[1] + dir.y() * t), (float)(eye[2] + dir.z() * t)), end;
        double left = tend - t;
        if (left <= 0) return OCC_VISIBLE;
        if (tree.castRay(o, dir, end, false, left)) {
            if (end.z() < ground_z + c.ground_clearance_m) {   /* ground: go on past it */
                t += (end - o).norm() + c.resolution;
                continue;
            }
            *occ = (float)(t + (end - o).norm());
            return OCC_HIDDEN;
        }
        /* false: reached the end (visible) or met an unknown voxel */
        return (end - o).norm() < left - c.resolution ? OCC_UNKNOWN : OCC_VISIBLE;
    }
    return OCC_UNKNOWN;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: occlusion-bench --log DRIVE.lcm --out OUT.lcm [--stock-from N] [--stock-count M]\n"
               "Times the occlusion pipeline on every sweep of a simdrive --scenario log, and stock\n"
               "OctoMap insertPointCloud + castRay on sweeps N..N+M-1; writes both answers to OUT.\n");
}

int main(int argc, char **argv)
{
    const char *log_path = nullptr, *out_path = nullptr;
    std::string vehicle = std::string(PB_SOURCE_DIR) + "/vehicles/prius2017.yaml";
    long stock_from = 300, stock_count = 30;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &log_path), PB_OPT_REQUIRED("out", &out_path),
        PB_OPT_LONG("stock-from", &stock_from, 0, 1L << 40), PB_OPT_LONG("stock-count", &stock_count, 0, 1L << 40),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("occlusion-bench", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    pb_vehicle_t veh;
    if (pb_vehicle_load(vehicle.c_str(), &veh, &err)) { fprintf(stderr, "occlusion-bench: %s\n", err.msg); return 1; }
    pb_log_t *in = pb_log_open_read(log_path, &err);
    if (!in) { fprintf(stderr, "occlusion-bench: %s\n", err.msg); return 1; }
    pb_log_out_t out = {};
    out.log = pb_log_open_write(out_path, &err);
    if (!out.log) { fprintf(stderr, "occlusion-bench: %s\n", err.msg); return 1; }

    occ_config_t cfg;
    occlusion_vehicle_t ov = {};
    ov.base_from_lidar = veh.base_from_lidar;
    memcpy(ov.seat_eye, veh.seat_eye_xyz, sizeof ov.seat_eye);
    ov.has_seat_eye = veh.has_seat_eye;
    ov.length = veh.length; ov.width = veh.width; ov.height = veh.height; ov.rear_overhang = veh.rear_overhang;
    occlusion_t *occ = occlusion_create(&cfg, &ov);
    occlusion_set_clock(occ, pb_clock_thread_cpu_ms);
    octomap::OcTree stock(cfg.resolution);

    std::vector<double> integ, query100, stock_insert, stock_query100, ours_rays_us, stock_rays_us;
    std::vector<occ_output_t> res;
    std::string mem_rows;   /* sweep, map leaves, map bytes, RSS kB; ... */
    std::vector<occ_event_t> ev;
    pb_points_t pts = {};
    long sweep = 0;
    int64_t last_pose_utime = 0;
    double last_pose[3] = { 0, 0, 0 }, last_q[4] = { 1, 0, 0, 0 };
    pb_event_t e;
    int r;
    while ((r = pb_log_next(in, &e, &err)) == 1) {
        std::string ch = e.channel;
        res.clear(); ev.clear();
        if (ch == "GROUND_TRUTH") {
            portobello_pose_t p;
            if (portobello_pose_t_decode(e.data, 0, e.datalen, &p) < 0) continue;
            occ_pose_in_t q;
            q.utime = p.utime;
            memcpy(q.pos, p.position, sizeof q.pos); memcpy(q.q, p.orientation, sizeof q.q); memcpy(q.vel, p.velocity, sizeof q.vel);
            q.usable = true;
            last_pose_utime = p.utime;
            memcpy(last_pose, p.position, sizeof last_pose); memcpy(last_q, p.orientation, sizeof last_q);
            occlusion_pose(occ, &q, &res, &ev);
        } else if (ch == "HEAD_POSE") {
            portobello_head_pose_t h;
            if (portobello_head_pose_t_decode(e.data, 0, e.datalen, &h) < 0) continue;
            occlusion_head(occ, h.utime, h.position, h.tracking);
        } else if (ch == "AGENTS") {
            portobello_agents_t a;
            if (portobello_agents_t_decode(e.data, 0, e.datalen, &a) < 0) continue;
            std::vector<occ_agent_in_t> ag(a.nagents);
            for (int i = 0; i < a.nagents; i++) {
                ag[i].id = a.agents[i].id; ag[i].kind = a.agents[i].kind;
                memcpy(ag[i].pos, a.agents[i].position, sizeof ag[i].pos);
                memcpy(ag[i].vel, a.agents[i].velocity, sizeof ag[i].vel);
                ag[i].yaw = a.agents[i].yaw_rad;
                ag[i].in_render_range = a.agents[i].in_render_range;
            }
            occlusion_agents(occ, a.utime, ag);
            portobello_agents_t_decode_cleanup(&a);
        } else if (ch == "LIDAR_SCAN") {
            portobello_lidar_scan_t s;
            if (portobello_lidar_scan_t_decode(e.data, 0, e.datalen, &s) < 0) continue;
            if (pb_scan_points(&s, &pts, &err) >= 0) occlusion_scan(occ, s.utime, &pts, &res, &ev);
            portobello_lidar_scan_t_decode_cleanup(&s);
        }
        for (occ_output_t &o : res) {
            write_occ(&out, "OCCLUSION", o);
            if (!o.pose_ok) { sweep++; continue; }
            integ.push_back(o.integrate_ms);
            if (sweep % 600 == 0) {     /* memory once a minute of drive */
                int64_t lv, by;
                occ_map_size(occlusion_map(occ), &lv, &by);
                mem_rows += (mem_rows.empty() ? "" : ", ") + std::to_string(sweep) + ", " + std::to_string(lv) + ", " +
                            std::to_string(by) + ", " + std::to_string(rss_kb());
            }
            /* 100 agents: the in-range agents' samples, repeated */
            std::vector<const occ_agent_out_t *> inr;
            for (const occ_agent_out_t &g : o.agents)
                if (g.evaluated) inr.push_back(&g);
            double yaw = std::atan2(2 * (last_q[0] * last_q[3] + last_q[1] * last_q[2]), 1 - 2 * (last_q[2] * last_q[2] + last_q[3] * last_q[3]));
            const occ_map_t *map = occlusion_map(occ);
            int8_t st[PB_BODY_MAX_SAMPLES];
            float om[PB_BODY_MAX_SAMPLES];
            int rays = 0;
            if (!inr.empty()) {
                double t0 = pb_clock_thread_cpu_ms();
                for (int k = 0; k < 100; k++) {
                    const occ_agent_out_t *g = inr[k % inr.size()];
                    occ_map_query(map, o.viewer, last_pose, yaw, g->x, g->y, g->z, g->n, st, om);
                    rays += g->n;
                }
                double dt = pb_clock_thread_cpu_ms() - t0;
                query100.push_back(dt);
                ours_rays_us.push_back(dt * 1e3 / rays);
            }
            /* stock OctoMap on the chosen sweeps (warm-up sweeps untimed): the same points */
            occ_sweep_t sw;
            if (sweep >= stock_from - 10 && sweep < stock_from + stock_count && occlusion_last_sweep(occ, &sw)) {
                octomap::Pointcloud cloud;
                octomap::point3d so((float)sw.mid_origin[0], (float)sw.mid_origin[1], (float)sw.mid_origin[2]);
                for (int i = 0; i < sw.n; i++) {
                    octomap::point3d p(sw.x[i], sw.y[i], sw.z[i]);
                    if (std::isfinite(sw.x[i]) && (p - so).norm() <= cfg.range_m) cloud.push_back(p);
                }
                double t0 = pb_clock_thread_cpu_ms();
                stock.insertPointCloud(cloud, so, cfg.range_m);
                double t1 = pb_clock_thread_cpu_ms();
                occ_output_t so_out = o;
                auto ask = [&](const occ_agent_out_t &g, int8_t *state, float *occm) {
                    for (int k = 0; k < g.n; k++) {
                        double d[3] = { g.x[k] - o.viewer[0], g.y[k] - o.viewer[1], g.z[k] - o.viewer[2] };
                        double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                        for (double &v : d) v /= len;
                        double te = occ_map_ego_exit(map, o.viewer, d, last_pose, yaw);
                        state[k] = stock_query(stock, cfg, o.viewer, te, last_pose[2], g.x[k], g.y[k], g.z[k], &occm[k]);
                    }
                };
                if (sweep >= stock_from) {
                    stock_insert.push_back(t1 - t0);
                    if (!inr.empty()) {
                        int rays2 = 0;
                        double q0 = pb_clock_thread_cpu_ms();
                        for (int k = 0; k < 100; k++) { ask(*inr[k % inr.size()], st, om); rays2 += inr[k % inr.size()]->n; }
                        double dq = pb_clock_thread_cpu_ms() - q0;
                        stock_query100.push_back(dq);
                        stock_rays_us.push_back(dq * 1e3 / rays2);
                    }
                    for (occ_agent_out_t &g : so_out.agents) {
                        if (!g.evaluated) continue;   /* not evaluated by ours either */
                        ask(g, g.state, g.occluder_m);
                        int vis = 0;
                        for (int k = 0; k < g.n; k++) vis += g.state[k] == OCC_VISIBLE;
                        g.visible_fraction = (float)vis / g.n;
                    }
                    write_occ(&out, "OCCLUSION_STOCK", so_out);
                }
                fprintf(stderr, "occlusion-bench: sweep %ld: stock insert %.0f ms\n", sweep, t1 - t0);
            }
            sweep++;
        }
        if (out.failed) break;
    }
    (void)last_pose_utime;
    if (r < 0) fprintf(stderr, "occlusion-bench: %s\n", err.msg);
    occlusion_finish(occ, &res, &ev);
    int64_t leaves, bytes;
    occ_map_size(occlusion_map(occ), &leaves, &bytes);
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);     /* peak resident memory of the whole run (stock tree included) */
    printf("{\"rss_max_kb\": %ld, \"rss_end_kb\": %ld, \"sweeps\": %zu, \"integrate_ms_p50\": %.3f, \"integrate_ms_p99\": %.3f, \"query100_ms_p50\": %.4f, "
           "\"query100_ms_p99\": %.4f, \"ours_us_per_ray_p50\": %.4f, \"stock_sweeps\": %zu, \"stock_insert_ms_p50\": %.1f, "
           "\"stock_insert_ms_p99\": %.1f, \"stock_query100_ms_p50\": %.3f, \"stock_us_per_ray_p50\": %.3f, "
           "\"map_leaves_end\": %lld, \"map_bytes_end\": %lld, \"memory_per_minute\": [%s]}\n",
           (long)ru.ru_maxrss, rss_kb(), integ.size(), pct(integ, 0.5), pct(integ, 0.99), pct(query100, 0.5), pct(query100, 0.99), pct(ours_rays_us, 0.5),
           stock_insert.size(), pct(stock_insert, 0.5), pct(stock_insert, 0.99), pct(stock_query100, 0.5),
           pct(stock_rays_us, 0.5), (long long)leaves, (long long)bytes, mem_rows.c_str());
    pb_log_close(out.log, &err);
    pb_log_close(in, &err);
    occlusion_destroy(occ);
    pb_points_free(&pts);
    return r < 0 ? 1 : 0;
}
