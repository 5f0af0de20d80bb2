// mapper: the log read sweep by sweep, the car's own body cut out (mapper.h).
#include <atomic>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include "mapper.h"
#include "portobello_lidar_scan_t.h"

/* The car's own body in base (xmin, ymin, zmin, xmax, ymax, zmax), 10 cm larger than the
 * vehicle file's box, as the localizer's: returns from it (a roof the mount lets beams reach)
 * would be mapped along the whole drive. */
struct BodyBox {
    double b[6];
    explicit BodyBox(const pb_vehicle_t &v) { pb_vehicle_body_box(&v, 0.10, b); }
    bool has(const Eigen::Vector3d &p) const
    {
        return p.x() >= b[0] && p.y() >= b[1] && p.z() >= b[2] && p.x() <= b[3] && p.y() <= b[4] && p.z() <= b[5];
    }
};

/* One event of the log as for_each_sweep's reader hands it on: a sweep decoded (its points
 * in base and in the lidar frame), another channel's event (its bytes copied), or the end. */
struct LogItem {
    enum { SWEEP, OTHER, END } kind = END;
    int64_t utime = 0;
    std::vector<float> xyz;
    pb_points_t pts = {};
    std::string channel;
    std::vector<uint8_t> data;
    pb_event_t ev = {};
    int status = 0;   /* END: 0 the log's end, -1 an error (err) */
    pb_err_t err;
    LogItem() = default;
    LogItem(const LogItem &) = delete;
    ~LogItem() { pb_points_free(&pts); }
};

/* Every LIDAR_SCAN of the log in turn after the first *seen (skipped unread), without the
 * points on the car's own body: fn(utime, points in base, the same points in the lidar
 * frame, event) returns 0 or -1; *seen counts the scans read (fn's included). other (if
 * given) sees every other event after the skipped scans, in log order, and returns 0 or -1.
 * read_ahead: the log is read and the sweeps decoded on a second thread, a few sweeps ahead
 * of fn (a pass whose own work is single-threaded: the decoding costs a fifth of the map
 * pass); fn and other run on the caller's thread, in log order, either way. */
int for_each_sweep(const char *log_path, const char *scan_ch, const pb_vehicle_t &veh, long every, long *seen,
                          pb_progress_t *prog, const SweepFn &fn, long *empty, pb_err_t *err, const OtherFn &other,
                   bool read_ahead)
{
    pb_log_t *log = pb_log_open_read(log_path, err);
    if (!log) return -1;
    int status = 0;
    std::atomic<bool> stop(false);
    /* one item to fn or other; false once one of them failed (the rest is drained) */
    auto consume = [&](LogItem &it) {
        if (it.kind == LogItem::END) {
            if (it.status != 0 && status == 0) { *err = it.err; status = -1; }
            return false;
        }
        if (status != 0) return false;
        int r;
        if (it.kind == LogItem::OTHER) {
            it.ev.channel = it.channel.c_str();
            it.ev.data = it.data.data();
            r = other(it.ev, err);
        } else {
            r = fn(it.utime, it.xyz, it.pts, it.ev, err);
        }
        if (r != 0) {
            pb_err_prefix(err, "%s: byte %lld: ", log_path, (long long)it.ev.offset);
            status = -1;
            stop = true;   /* the reader ends at its next event */
        }
        return r == 0;
    };
    std::mutex mu;
    std::condition_variable cv;
    std::deque<std::unique_ptr<LogItem>> queue;
    /* items consumed, taken again by the reader: a sweep's arrays keep their capacity
     * (a fresh megabyte a sweep would be page faults on the hot path) */
    std::vector<std::unique_ptr<LogItem>> spare;
    const size_t kAhead = 4;
    auto take = [&] {
        std::lock_guard<std::mutex> lk(mu);
        if (spare.empty()) return std::unique_ptr<LogItem>(new LogItem);
        std::unique_ptr<LogItem> it = std::move(spare.back());
        spare.pop_back();
        return it;
    };
    auto give_back = [&](std::unique_ptr<LogItem> it) {
        std::lock_guard<std::mutex> lk(mu);
        spare.push_back(std::move(it));
    };
    auto push = [&](std::unique_ptr<LogItem> it) {
        if (!read_ahead) { consume(*it); give_back(std::move(it)); return; }
        std::unique_lock<std::mutex> lk(mu);
        cv.wait(lk, [&] { return queue.size() < kAhead || stop; });
        queue.push_back(std::move(it));
        cv.notify_all();
    };
    auto read = [&] {
        const Eigen::Isometry3d base_from_lidar = pb_reg_from_transform(&veh.base_from_lidar);
        const BodyBox body(veh);
        const long skip = *seen;
        long nread = 0;
        pb_event_t ev;
        int rc = 0;
        std::unique_ptr<LogItem> end(new LogItem);
        while (!stop && (rc = pb_log_next(log, &ev, &end->err)) == 1) {
            if (std::strcmp(ev.channel, scan_ch) != 0) {
                if (!other || nread < skip) continue;
                std::unique_ptr<LogItem> it = take();
                it->kind = LogItem::OTHER;
                it->channel = ev.channel;
                it->data.assign(ev.data, ev.data + ev.datalen);
                it->ev = ev;
                push(std::move(it));
                continue;
            }
            if (nread++ < skip) continue;
            if (prog) pb_progress_update(prog, *seen);
            if ((*seen)++ % every) continue;
            portobello_lidar_scan_t s;
            if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) {
                pb_err_set(&end->err, "%s: byte %lld: %s does not decode as lidar_scan_t", log_path,
                           (long long)ev.offset, ev.channel);
                rc = -1;
                break;
            }
            std::unique_ptr<LogItem> it = take();
            int n = pb_scan_points(&s, &it->pts, &end->err);
            it->utime = s.utime;
            portobello_lidar_scan_t_decode_cleanup(&s);
            if (n < 0) {
                pb_err_prefix(&end->err, "%s: byte %lld: ", log_path, (long long)ev.offset);
                rc = -1;
                break;
            }
            pb_points_t &pts = it->pts;
            it->xyz.resize(3 * (size_t)n);
            int kept = 0;
            for (int i = 0; i < n; i++) {
                Eigen::Vector3d p = base_from_lidar * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
                if (body.has(p)) continue;
                float *q = &it->xyz[3 * (size_t)kept];
                q[0] = (float)p.x(); q[1] = (float)p.y(); q[2] = (float)p.z();
                pts.x[kept] = pts.x[i]; pts.y[kept] = pts.y[i]; pts.z[kept] = pts.z[i];
                pts.intensity[kept] = pts.intensity[i];
                pts.offset_us[kept] = pts.offset_us[i];
                pts.ring[kept] = pts.ring[i];
                kept++;
            }
            pts.n = kept;
            it->xyz.resize(3 * (size_t)kept);
            if (kept == 0) { (*empty)++; continue; }
            it->kind = LogItem::SWEEP;
            it->ev = ev;
            it->ev.data = nullptr;   /* the sweep's bytes are not kept */
            push(std::move(it));
        }
        end->kind = LogItem::END;
        end->status = rc < 0 ? -1 : 0;
        push(std::move(end));
    };
    if (!read_ahead) {
        read();
    } else {
        std::thread reader(read);
        for (bool more = true; more;) {
            std::unique_ptr<LogItem> it;
            {
                std::unique_lock<std::mutex> lk(mu);
                cv.wait(lk, [&] { return !queue.empty(); });
                it = std::move(queue.front());
                queue.pop_front();
            }
            more = it->kind != LogItem::END;
            consume(*it);
            give_back(std::move(it));
            std::lock_guard<std::mutex> lk(mu);
            cv.notify_all();
        }
        reader.join();
    }
    pb_log_close(log, nullptr);
    return status;
}

/* fn(D, utime, points in base, in the lidar frame, event, err) on every `every`-th sweep of
 * each placed drive D in turn, read ahead, each drive with its progress bar ("what"). */
int for_each_drive_sweep(Run *R, const char *what, long every, const DriveSweepFn &fn, pb_err_t *err)
{
    int rc = 0;
    for (Run *D : R->drives) {
        if (rc != 0 || !D->placement.placed) continue;
        long empty = 0, seen = 0;
        pb_progress_t prog;
        const std::string label = D->label(what);   /* the bar keeps the pointer */
        pb_progress_start(&prog, label.c_str(), D->total, R->quiet);
        rc = for_each_sweep(D->log_path, R->scan_ch, R->veh, every, &seen, &prog,
            [&](int64_t utime, const std::vector<float> &xyz, const pb_points_t &pts, const pb_event_t &ev, pb_err_t *e) {
                return fn(D, utime, xyz, pts, ev, e);
            }, &empty, err, nullptr, true);
        if (rc == 0) pb_progress_finish(&prog);
    }
    return rc;
}
