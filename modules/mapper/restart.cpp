// mapper: restart after an interruption (mapper.h, docs/mapper.md "Restart").
#include <sys/stat.h>
#include <unistd.h>
#include "mapper.h"
#include "pb_bytes.h"

/* ---- Restart after an interruption (docs/mapper.md, "Restart"). SITE_DIR/checkpoint.bin
 * holds the odometry pass so far (the sweeps' poses, the scans read, the odometry's state)
 * or, once it is over, the whole pass; the keyframes' points go to SITE_DIR/keyframes.bin,
 * appended at each checkpoint (the checkpoint says how many of its bytes are valid).
 * checkpoint.bin is written to .tmp, synced and renamed: an interruption leaves the last
 * whole one. A run that ends well removes both. */
static const char kCheckpointMagic[8] = {'P', 'B', 'M', 'A', 'P', 'C', 'K', '2'};

static void put_pose(ByteWriter &w, const Eigen::Isometry3d &T)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++) w.put(T.matrix()(r, c));
}

/* A keyframe's record in keyframes.bin: utime, pose (3 x 4 doubles), point count, then the
 * points (x y z floats). */
static const size_t kKeyframeHead = 8 + 12 * 8 + 8;

static Eigen::Isometry3d get_pose(ByteReader &r)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    for (int i = 0; i < 3; i++)
        for (int c = 0; c < 4; c++) T.matrix()(i, c) = r.get<double>();
    return T;
}

/* What a checkpoint must match: the log (size and its first MiB), the mapper's build (the
 * executable's size and time: another build may place the sweeps otherwise) and the options
 * the odometry depends on. */
int checkpoint_ids(Run *R, pb_err_t *err)
{
    FILE *f = std::fopen(R->log_path, "rb");
    if (!f) return pb_err_set(err, "%s: cannot open: %s", R->log_path, std::strerror(errno)), -1;
    std::vector<uint8_t> head(1 << 20);
    head.resize(std::fread(head.data(), 1, head.size(), f));
    struct stat st;
    const bool sized = fstat(fileno(f), &st) == 0;
    std::fclose(f);
    char buf[512];
    std::snprintf(buf, sizeof buf, "log of %lld bytes, first MiB %016llx", sized ? (long long)st.st_size : -1LL,
                  (unsigned long long)pb_fnv1a64(head.data(), head.size()));
    R->log_id = buf;
    struct stat ex;
    if (stat("/proc/self/exe", &ex) != 0) ex.st_size = ex.st_mtime = -1;
    std::snprintf(buf, sizeof buf, "mapper of %lld bytes at %lld", (long long)ex.st_size, (long long)ex.st_mtime);
    R->build_id = buf;
    const pb_transform_t &bl = R->veh.base_from_lidar;
    const pb_transform_t &bi = R->veh.base_from_imu;
    const pb_vehicle_t &v = R->veh;   /* the mounts and the body box the sweeps are cut by */
    std::snprintf(buf, sizeof buf, "channel %s, base <- lidar %.17g %.17g %.17g %.17g %.17g %.17g %.17g, "
                  "base <- imu %.17g %.17g %.17g %.17g, body %.17g %.17g %.17g %.17g", R->scan_ch,
                  bl.t[0], bl.t[1], bl.t[2], bl.q[0], bl.q[1], bl.q[2], bl.q[3], bi.q[0], bi.q[1], bi.q[2], bi.q[3],
                  v.length, v.width, v.height, v.rear_overhang);
    R->options_id = buf;
    return 0;
}

/* The whole file into *out; -1 when it cannot be opened or read. */
int read_file(const std::string &path, std::vector<uint8_t> *out)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return -1;
    out->clear();
    uint8_t chunk[1 << 16];
    size_t n;
    while ((n = std::fread(chunk, 1, sizeof chunk, f)) > 0) out->insert(out->end(), chunk, chunk + n);
    const bool ok = !std::ferror(f);
    std::fclose(f);
    return ok ? 0 : -1;
}

/* Writes the pieces one after the other to path through path.tmp, synced, renamed. */
int write_file_synced(const std::string &path, std::initializer_list<const std::vector<uint8_t> *> pieces,
                             pb_err_t *err)
{
    const std::string tmp = path + ".tmp";
    FILE *f = std::fopen(tmp.c_str(), "wb");
    bool ok = f != nullptr;
    for (const std::vector<uint8_t> *b : pieces) ok = ok && std::fwrite(b->data(), 1, b->size(), f) == b->size();
    ok = ok && std::fflush(f) == 0 && fsync(fileno(f)) == 0;
    if (f) ok &= std::fclose(f) == 0;
    if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
        std::remove(tmp.c_str());
        return pb_err_set(err, "%s: cannot write: %s", path.c_str(), std::strerror(errno)), -1;
    }
    return 0;
}

/* keyframes.bin's first n keyframes (utime, pose, where their record starts as points_key;
 * with_points: the points too) into *kf, which must hold bytes bytes. false when it does not. */
bool read_keyframes(const std::string &path, uint64_t n, uint64_t bytes, bool with_points,
                    std::vector<pb_keyframe_t> *kf)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    kf->resize(n);
    uint64_t at = 0;
    bool ok = true;
    for (pb_keyframe_t &k : *kf) {
        uint8_t head[kKeyframeHead];
        ok = std::fread(head, 1, sizeof head, f) == sizeof head;
        if (!ok) break;
        ByteReader r{head, head + sizeof head};
        k.utime = r.get<int64_t>();
        k.pose = get_pose(r);
        k.points_key = at;
        const uint64_t npts = r.get<uint64_t>();
        at += sizeof head + npts * sizeof(float);
        if (!(ok = at <= bytes)) break;
        if (with_points) {
            k.xyz.resize((size_t)npts);
            ok = std::fread(k.xyz.data(), sizeof(float), k.xyz.size(), f) == k.xyz.size();
        } else {
            ok = std::fseek(f, (long)(npts * sizeof(float)), SEEK_CUR) == 0;
        }
        if (!ok) break;
    }
    std::fclose(f);
    return ok && at == bytes;
}

int keyframe_points(FILE *f, const std::string &path, uint64_t at, std::vector<float> *xyz, pb_err_t *err)
{
    uint8_t head[kKeyframeHead];
    bool ok = std::fseek(f, (long)at, SEEK_SET) == 0 && std::fread(head, 1, sizeof head, f) == sizeof head;
    uint64_t npts = 0;
    if (ok) std::memcpy(&npts, head + sizeof head - 8, 8);
    ok = ok && npts < (1u << 28);
    if (ok) {
        xyz->resize((size_t)npts);
        ok = std::fread(xyz->data(), sizeof(float), xyz->size(), f) == xyz->size();
    }
    if (!ok) return pb_err_set(err, "%s: byte %llu: cannot read a keyframe's points back", path.c_str(), (unsigned long long)at), -1;
    return 0;
}

/* The keyframes not yet in keyframes.bin appended to it (their points then freed: read
 * back for the loops), then the checkpoint: odom the odometry in the middle of the pass,
 * NULL once the pass is over. */
int checkpoint_write(Run *R, const pb_odom_t *odom, pb_err_t *err)
{
    std::vector<uint8_t> buf;
    ByteWriter w{&buf};
    for (; R->kf_saved < R->kf.size(); R->kf_saved++) {
        pb_keyframe_t &k = R->kf[R->kf_saved];
        w.put(k.utime);
        put_pose(w, k.pose);
        w.put_array(k.xyz.data(), k.xyz.size());
        std::vector<float>().swap(k.xyz);
    }
    if (std::fwrite(buf.data(), 1, buf.size(), R->kf_file) != buf.size() || std::fflush(R->kf_file) != 0 ||
        fsync(fileno(R->kf_file)) != 0)
        return pb_err_set(err, "%s: cannot write: %s", R->work("keyframes").c_str(), std::strerror(errno)), -1;
    R->kf_bytes += buf.size();
    buf.clear();
    for (char c : kCheckpointMagic) w.put(c);
    w.put_string(R->log_id); w.put_string(R->build_id); w.put_string(R->options_id);
    w.put((uint8_t)(odom == nullptr));
    w.put((int64_t)R->seen); w.put(R->last_scan_utime); w.put((int64_t)R->empty); w.put((int64_t)R->out_of_order);
    w.put((uint64_t)R->traj.size());
    for (const SweepPose &sp : R->traj) {
        w.put(sp.utime);
        put_pose(w, sp.odometry);
        w.put(sp.status); w.put(sp.motion); w.put(sp.inlier_fraction); w.put(sp.cpu_ms); w.put(sp.keyframe);
        w.put(sp.measured_mps);
    }
    w.put((uint64_t)R->kf.size()); w.put(R->kf_bytes);
    std::vector<uint8_t> state, sum;   /* the state (tens of MB) written as it is, not copied */
    if (odom) pb_odom_save(odom, &state);
    w.put((uint64_t)state.size());
    ByteWriter{&sum}.put(pb_fnv1a64(state.data(), state.size(), pb_fnv1a64(buf.data(), buf.size())));
    return write_file_synced(R->work("checkpoint"), {&buf, &state, &sum}, err);
}

/* A checkpoint of this log, build and options restored into R (R->resumed_from > 0); one
 * of another (or damaged) is refused, its reason in R->checkpoint_refused and on stderr,
 * and the run starts over. Returns -1 only on an error reading a file there. */
int checkpoint_read(Run *R, pb_err_t *err)
{
    const std::string path = R->work("checkpoint"), kf_path = R->work("keyframes");
    std::vector<uint8_t> buf;
    if (read_file(path, &buf) != 0) return 0;   /* none: a fresh start */
    ByteReader r{buf.data(), buf.data() + buf.size()};
    std::string why;
    bool magic = buf.size() >= 16;
    for (char c : kCheckpointMagic) magic &= r.get<char>() == c;
    uint64_t sum = 0;
    if (magic) std::memcpy(&sum, buf.data() + buf.size() - 8, 8);
    std::string log_id = r.get_string(), build_id = r.get_string(), options_id = r.get_string();
    if (!magic) why = "not a checkpoint of this version of the mapper";
    else if (sum != pb_fnv1a64(buf.data(), buf.size() - 8)) why = "damaged (checksum)";
    else if (log_id != R->log_id) why = "from another log (" + log_id + "; this one: " + R->log_id + ")";
    else if (build_id != R->build_id) why = "from another build of the mapper (" + build_id + "; this one: " + R->build_id + ")";
    else if (options_id != R->options_id) why = "made with other options (" + options_id + "; now: " + R->options_id + ")";
    const bool done = r.get<uint8_t>() != 0;
    const long seen = (long)r.get<int64_t>();
    R->last_scan_utime = r.get<int64_t>();
    R->empty = (long)r.get<int64_t>();
    R->out_of_order = (long)r.get<int64_t>();
    const uint64_t ntraj = r.get<uint64_t>();
    for (uint64_t i = 0; why.empty() && r.ok && i < ntraj; i++) {
        SweepPose sp;
        sp.utime = r.get<int64_t>();
        sp.pose = sp.odometry = get_pose(r);
        sp.status = r.get<int>(); sp.motion = r.get<int>(); sp.inlier_fraction = r.get<double>();
        sp.cpu_ms = r.get<double>();
        sp.keyframe = r.get<int>();
        sp.measured_mps = r.get<double>();
        if (sp.status < kGiven || sp.status > PB_ODOM_PREVIOUS || sp.motion < kGiven || sp.motion > PB_ODOM_MOTION_MEASURED)
            why = "damaged (a sweep's status out of range)";   /* the report counts by them */
        R->traj.push_back(sp);
    }
    const uint64_t nkf = r.get<uint64_t>();
    R->kf_bytes = r.get<uint64_t>();
    std::vector<uint8_t> state;
    r.get_array(&state);
    if (why.empty() && (!r.ok || r.p != buf.data() + buf.size() - 8)) why = "damaged (truncated)";
    // the keyframes it counts, from keyframes.bin (their points stay there until the loops)
    if (why.empty() && !read_keyframes(kf_path, nkf, R->kf_bytes, false, &R->kf))
        why = "keyframes.bin does not hold the keyframes the checkpoint says";
    pb_err_t e;
    if (why.empty() && !done && !(R->odom = pb_odom_restore(state.data(), state.size(), &R->odom_cfg, &R->reg, &e))) why = e.msg;
    if (!why.empty()) {
        R->checkpoint_refused = why;
        R->traj.clear(); R->kf.clear();
        R->empty = R->out_of_order = 0; R->last_scan_utime = 0; R->kf_bytes = 0;
        std::fprintf(stderr, "mapper: %s: %s; starting over\n", path.c_str(), why.c_str());
        return 0;
    }
    // keyframes.bin cut to what the checkpoint counts (an interruption may have left more)
    if (truncate(kf_path.c_str(), (off_t)R->kf_bytes) != 0)
        return pb_err_set(err, "%s: cannot truncate: %s", kf_path.c_str(), std::strerror(errno)), -1;
    R->kf_saved = R->kf.size();
    R->seen = R->resumed_from = seen;
    R->odometry_done = done;
    std::fprintf(stderr, "mapper: resuming from %s: %ld of %ld scans read%s\n", path.c_str(), seen, R->total,
                 done ? ", the odometry done" : "");
    return 0;
}

/* ---- Restart inside the later steps (mapper.h). */
const char kPosesMagic[8] = {'P', 'B', 'M', 'A', 'P', 'P', 'S', '2'};   /* 2: each drive's GNSS clock offset */
const char kCarvedMagic[8] = {'P', 'B', 'M', 'A', 'P', 'C', 'V', '6'};

/* What a stage checkpoint must match: the mapper's build, the options the later steps depend
 * on, every drive's log (as the odometry's checkpoints) and the poses given. */
std::string stage_id(const Run *R)
{
    char buf[128];
    std::snprintf(buf, sizeof buf, "; voxel %.17g, tile %.17g", R->voxel, R->tile_m);
    std::string id = R->build_id + "; " + R->options_id + buf;
    for (const Run *D : R->drives) id += "; " + D->log_id;
    std::vector<uint8_t> poses;
    if (R->poses_path && read_file(R->poses_path, &poses) == 0) {
        std::snprintf(buf, sizeof buf, "; poses of %zu bytes %016llx", poses.size(),
                      (unsigned long long)pb_fnv1a64(poses.data(), poses.size()));
        id += buf;
    }
    return id;
}

/* buf (magic, the run's id, the step's state) and its checksum to SITE_DIR/name. */
static int stage_write(Run *R, const char *name, std::vector<uint8_t> *buf, pb_err_t *err)
{
    std::vector<uint8_t> sum;
    ByteWriter{&sum}.put(pb_fnv1a64(buf->data(), buf->size()));
    return write_file_synced(R->path(name), {buf, &sum}, err);
}

/* SITE_DIR/name read and checked (magic, checksum, id); "" and r over the state, or why not. */
static std::string stage_open(const Run *R, const char *name, const char magic[8], std::vector<uint8_t> *buf,
                              ByteReader *r, uint64_t *sum)
{
    if (read_file(R->path(name), buf) != 0) return "none";
    *r = ByteReader{buf->data(), buf->data() + buf->size()};
    bool ok = buf->size() >= 16;
    for (int i = 0; i < 8; i++) ok &= r->get<char>() == magic[i];
    if (!ok) return "not a checkpoint of this version of the mapper";
    std::memcpy(sum, buf->data() + buf->size() - 8, 8);
    if (*sum != pb_fnv1a64(buf->data(), buf->size() - 8)) return "damaged (checksum)";
    r->end -= 8;
    const std::string id = r->get_string(), now = stage_id(R);
    if (id != now) return "made for another run (" + id + "; this one: " + now + ")";
    return "";
}

static void put_str(ByteWriter &w, const char *s) { w.put_string(s ? s : ""); }

int stage_write_poses(Run *R, pb_err_t *err)
{
    std::vector<uint8_t> buf;
    ByteWriter w{&buf};
    for (char c : kPosesMagic) w.put(c);
    w.put_string(stage_id(R));
    for (const Run *D : R->drives) {
        w.put((uint64_t)D->traj.size());
        for (const SweepPose &sp : D->traj) { put_pose(w, sp.pose); put_pose(w, sp.odometry); }
        const pb_drive_report_t &p = D->placement;
        w.put((uint8_t)p.placed); put_str(w, p.why); w.put(p.tried); w.put(p.matched); w.put(p.links);
        put_pose(w, p.placement);
        w.put(D->gnss_clock_offset_us); w.put(D->gnss_clock_lags);
    }
    const pb_loops_report_t &l = R->loops;
    for (int v : {l.candidates, l.verified, l.rejected, l.dropped, l.place_candidates, l.place_loops, l.iterations}) w.put(v);
    w.put(l.max_change_m);
    w.put((uint64_t)R->loop_times.size());
    for (const auto &lt : R->loop_times) { w.put(lt.first.first); w.put(lt.first.second); w.put(lt.second.first); w.put(lt.second.second); }
    const pb_anchor_result_t &a = R->anchor;
    w.put(a.anchored); put_str(w, a.why); put_pose(w, a.enu_from_map);
    for (int v : {a.used, a.gated, a.rejected}) w.put(v);
    for (double v : {a.resid_median_m, a.resid_p90_m, a.resid_max_m, a.extent_m}) w.put(v);
    const pb_anchor_hold_result_t &h = R->hold;
    for (int v : {h.held, h.nodes, h.fixes, h.links, h.iterations}) w.put(v);
    for (double v : {h.ratio, h.max_change_m, h.step_scale, h.resid_p90_m}) w.put(v);
    const pb_georef_t &g = R->georef;
    for (double v : {g.lat0_deg, g.lon0_deg, g.alt0_m, g.yaw_deg}) w.put(v);
    std::vector<double> fixes;
    for (const Eigen::Vector3d &f : R->layers.fixes) fixes.insert(fixes.end(), {f.x(), f.y(), f.z()});
    w.put_array(fixes.data(), fixes.size());
    w.put(R->peak_mb[0]); w.put(R->peak_mb[1]);
    if (stage_write(R, "poses.bin", &buf, err) != 0) return -1;
    R->poses_sum = pb_fnv1a64(buf.data(), buf.size());
    return 0;
}

int stage_write_carved(Run *R, pb_err_t *err)
{
    std::vector<uint8_t> buf;
    ByteWriter w{&buf};
    for (char c : kCarvedMagic) w.put(c);
    w.put_string(stage_id(R));
    w.put(R->poses_sum);
    for (long v : {R->placed, R->unplaced, R->tiles_held_max, R->carve_tiles_held_max, R->tiles_paged_out,
                   R->carve_tiles_paged_out, R->tiles_paged_in, R->carve_tiles_paged_in, R->beyond_range})
        w.put((int64_t)v);
    w.put(R->voxels_held_max); w.put((uint64_t)R->voxels); w.put((uint64_t)R->map_points); w.put((uint64_t)R->carved);
    w.put((uint64_t)R->carved_groups); w.put((int64_t)R->views);
    for (uint64_t v : {R->under_returns, (uint64_t)R->under_moved, (uint64_t)R->under_gone}) w.put(v);
    std::vector<int64_t> tiles(R->carve_tiles.begin(), R->carve_tiles.end());
    w.put_array(tiles.data(), tiles.size());
    std::vector<uint64_t> kept;   /* per kept tile: key, seq of its first point, bytes, checksum */
    for (size_t t = 0; t < R->kept_tiles.size(); t++)
        kept.insert(kept.end(), {(uint64_t)R->kept_tiles[t].first, R->kept_tiles[t].second, R->kept_sums[t].first,
                                 R->kept_sums[t].second});
    w.put_array(kept.data(), kept.size());
    w.put_string(R->ground_why);
    w.put_array(R->layers.removed.data(), R->layers.removed.size());
    w.put_array(R->layers.objects.data(), R->layers.objects.size());
    w.put(R->peak_mb[2]); w.put(R->peak_mb[3]);
    return stage_write(R, "carved.bin", &buf, err);
}

/* carved.bin's kept tiles as they were written (sizes and checksums). */
static bool kept_tiles_intact(const Run *R)
{
    std::vector<uint8_t> bytes;
    for (size_t t = 0; t < R->kept_tiles.size(); t++)
        if (read_file(tile_path(R, 'k', R->kept_tiles[t].first), &bytes) != 0 || bytes.size() != R->kept_sums[t].first ||
            pb_fnv1a64(bytes.data(), bytes.size()) != R->kept_sums[t].second)
            return false;
    return true;
}

int stage_read(Run *R, int *done, pb_err_t *)
{
    *done = 0;
    std::vector<uint8_t> buf;
    ByteReader r{nullptr, nullptr};
    uint64_t sum = 0;
    std::string why = stage_open(R, "poses.bin", kPosesMagic, &buf, &r, &sum);
    if (why == "none") return 0;
    // poses.bin: every drive's poses and placement, the loops' and anchoring's results
    std::vector<std::string> whys;
    std::vector<std::vector<std::pair<Eigen::Isometry3d, Eigen::Isometry3d>>> poses(R->drives.size());
    std::vector<pb_drive_report_t> placement(R->drives.size());
    std::vector<std::pair<int64_t, int>> clock(R->drives.size());   /* GNSS clock offset, lags */
    pb_loops_report_t loops{};
    std::vector<std::pair<SweepKey, SweepKey>> loop_times;
    pb_anchor_result_t anchor{};
    for (size_t d = 0; why.empty() && d < R->drives.size(); d++) {
        const uint64_t n = r.get<uint64_t>();
        if (n != R->drives[d]->traj.size()) { why = "for another trajectory"; break; }
        for (uint64_t i = 0; i < n && r.ok; i++) {
            Eigen::Isometry3d p = get_pose(r);
            poses[d].push_back({p, get_pose(r)});
        }
        pb_drive_report_t &p = placement[d];
        p.placed = r.get<uint8_t>() != 0;
        whys.push_back(r.get_string());
        p.tried = r.get<int>(); p.matched = r.get<int>(); p.links = r.get<int>();
        p.placement = get_pose(r);
        clock[d] = {r.get<int64_t>(), r.get<int>()};
    }
    if (why.empty()) {
        for (int *v : {&loops.candidates, &loops.verified, &loops.rejected, &loops.dropped, &loops.place_candidates,
                       &loops.place_loops, &loops.iterations}) *v = r.get<int>();
        loops.max_change_m = r.get<double>();
        const uint64_t nl = r.get<uint64_t>();
        for (uint64_t i = 0; i < nl && r.ok; i++) {
            SweepKey a, b;
            a.first = r.get<int>(); a.second = r.get<int64_t>(); b.first = r.get<int>(); b.second = r.get<int64_t>();
            loop_times.push_back({a, b});
        }
        anchor.anchored = r.get<int>();
        whys.push_back(r.get_string());
        anchor.enu_from_map = get_pose(r);
        for (int *v : {&anchor.used, &anchor.gated, &anchor.rejected}) *v = r.get<int>();
        for (double *v : {&anchor.resid_median_m, &anchor.resid_p90_m, &anchor.resid_max_m, &anchor.extent_m}) *v = r.get<double>();
    }
    pb_anchor_hold_result_t hold{};
    for (int *v : {&hold.held, &hold.nodes, &hold.fixes, &hold.links, &hold.iterations}) *v = r.get<int>();
    for (double *v : {&hold.ratio, &hold.max_change_m, &hold.step_scale, &hold.resid_p90_m}) *v = r.get<double>();
    pb_georef_t georef{};
    for (double *v : {&georef.lat0_deg, &georef.lon0_deg, &georef.alt0_m, &georef.yaw_deg}) *v = r.get<double>();
    std::vector<double> fix_xyz;
    r.get_array(&fix_xyz);
    const double peak0 = r.get<double>(), peak1 = r.get<double>();
    if (why.empty() && (!r.ok || r.p != r.end)) why = "damaged (truncated)";
    if (!why.empty()) {
        R->stage_refused = "poses.bin: " + why;
        std::fprintf(stderr, "mapper: %s: %s; the loops and what follows run again\n", R->path("poses.bin").c_str(), why.c_str());
        return 0;
    }
    // restored: the strings the reports point to kept in R->why_kept
    size_t at = 0;
    for (const std::string &w : whys) at += w.size() + 1;
    R->why_kept.clear();
    R->why_kept.reserve(at);
    std::vector<const char *> why_at;
    for (const std::string &w : whys) { why_at.push_back(R->why_kept.data() + R->why_kept.size()); R->why_kept.append(w).push_back('\0'); }
    for (size_t d = 0; d < R->drives.size(); d++) {
        Run *D = R->drives[d];
        for (size_t i = 0; i < D->traj.size(); i++) { D->traj[i].pose = poses[d][i].first; D->traj[i].odometry = poses[d][i].second; }
        D->placement = placement[d];
        D->placement.why = why_at[d];
        D->gnss_clock_offset_us = clock[d].first;
        D->gnss_clock_lags = clock[d].second;
    }
    R->loops = loops;
    R->loop_times = loop_times;
    R->anchor = anchor;
    R->anchor.why = why_at.back();
    R->hold = hold;
    R->georef = georef;
    R->layers.fixes.clear();
    for (size_t i = 0; i + 2 < fix_xyz.size(); i += 3) R->layers.fixes.emplace_back(fix_xyz[i], fix_xyz[i + 1], fix_xyz[i + 2]);
    R->peak_mb[0] = peak0;
    R->peak_mb[1] = peak1;
    R->poses_sum = sum;
    R->resumed_after = "loops";
    *done = 1;
    // carved.bin: the map made and carved
    why = stage_open(R, "carved.bin", kCarvedMagic, &buf, &r, &sum);
    if (why == "none") return 0;
    if (why.empty() && r.get<uint64_t>() != R->poses_sum) why = "made after another poses.bin";
    std::vector<int64_t> counts(9), tiles;
    for (int64_t &v : counts) v = r.get<int64_t>();
    const int64_t voxels_held_max = r.get<int64_t>();
    const uint64_t voxels = r.get<uint64_t>(), map_points = r.get<uint64_t>(), carved = r.get<uint64_t>();
    const uint64_t carved_groups = r.get<uint64_t>();
    const int64_t views = r.get<int64_t>();
    uint64_t under[3];
    for (uint64_t &v : under) v = r.get<uint64_t>();
    r.get_array(&tiles);
    std::vector<uint64_t> kept;
    r.get_array(&kept);
    R->kept_tiles.clear();
    R->kept_sums.clear();
    for (size_t i = 0; i + 3 < kept.size(); i += 4) {
        R->kept_tiles.push_back({(int64_t)kept[i], (uint32_t)kept[i + 1]});
        R->kept_sums.push_back({kept[i + 2], kept[i + 3]});
    }
    const std::string ground_why = r.get_string();
    std::vector<float> removed, objects;
    r.get_array(&removed);
    r.get_array(&objects);
    const double peak2 = r.get<double>(), peak3 = r.get<double>();
    if (why.empty() && (!r.ok || r.p != r.end || kept.size() % 4 != 0)) why = "damaged (truncated)";
    struct stat st;
    if (why.empty() && ground_why.empty() && stat(R->path("ground.yaml").c_str(), &st) != 0) why = "ground.yaml is gone";
    if (why.empty() && !kept_tiles_intact(R)) why = "the map's tiles in map-tiles.tmp are not as it wrote them";
    if (!why.empty()) {
        R->kept_tiles.clear();
        R->kept_sums.clear();
        R->stage_refused = "carved.bin: " + why;
        std::fprintf(stderr, "mapper: %s: %s; the map and the carving run again\n", R->path("carved.bin").c_str(), why.c_str());
        return 0;
    }
    long *dst[9] = {&R->placed, &R->unplaced, &R->tiles_held_max, &R->carve_tiles_held_max, &R->tiles_paged_out,
                    &R->carve_tiles_paged_out, &R->tiles_paged_in, &R->carve_tiles_paged_in, &R->beyond_range};
    for (int i = 0; i < 9; i++) *dst[i] = (long)counts[(size_t)i];
    R->voxels_held_max = voxels_held_max;
    R->voxels = (size_t)voxels;
    R->map_points = (size_t)map_points;
    R->carved = (size_t)carved;
    R->carved_groups = (size_t)carved_groups;
    R->views = (long)views;
    R->under_returns = under[0];
    R->under_moved = (size_t)under[1];
    R->under_gone = (size_t)under[2];
    R->carve_tiles = std::set<int64_t>(tiles.begin(), tiles.end());
    R->ground_why = ground_why;
    R->layers.removed = removed;
    R->layers.objects = objects;
    R->peak_mb[2] = peak2;
    R->peak_mb[3] = peak3;
    R->resumed_after = "carve";
    *done = 2;
    return 0;
}
