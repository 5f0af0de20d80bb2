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
static const char kCheckpointMagic[8] = {'P', 'B', 'M', 'A', 'P', 'C', 'K', '1'};

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
    if (why.empty() && !done && !(R->odom = pb_odom_restore(state.data(), state.size(), nullptr, nullptr, &e))) why = e.msg;
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
