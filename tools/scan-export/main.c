/* scan-export: the LIDAR_SCAN sweeps of a log as plain point files, for tools outside the
 * project (the KISS-ICP baseline of make bench-mapper) that should not decode sweeps
 * themselves. Points come from common/pb_scan (pb_scan_points), the one decoder of both
 * sweep forms.
 *   scan-export --log DRIVE.lcm --out DIR [--every N] [--vehicle FILE] [--quiet] */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "pb_log.h"
#include "pb_math.h"
#include "pb_opt.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"

#define DEFAULT_VEHICLE PB_SOURCE_DIR "/vehicles/prius2017.yaml"

static void usage(FILE *f)
{
    fprintf(f,
            "usage: scan-export --log DRIVE.lcm --out DIR [--every N] [--vehicle FILE] [--quiet]\n"
            "Writes every LIDAR_SCAN of a log as points in the lidar frame (decoded by\n"
            "common/pb_scan: range-image and point sweeps alike; no-return pixels dropped):\n"
            "  DIR/scans/NNNNNN.bin   one file per sweep, NNNNNN = the sweep's index in the log\n"
            "                         (0-based, LIDAR_SCAN events only); per point 4 little-endian\n"
            "                         float32: x y z (m, lidar frame) and t (s after the sweep's utime)\n"
            "  DIR/times.txt          the sweeps' utime in seconds (6 decimals), one a line, in the\n"
            "                         order of the files\n"
            "  DIR/ground_truth.tum   GROUND_TRUTH of the log (base in map), TUM \"t x y z qx qy qz qw\",\n"
            "                         t = utime / 1e6; only if the log has GROUND_TRUTH\n"
            "  DIR/base_from_lidar.txt  the base <- lidar extrinsic as a 4x4 row-major matrix ('#' lines\n"
            "                         say where it came from)\n"
            "  --log DRIVE.lcm   the log\n"
            "  --out DIR         output folder (created; files of an earlier export are overwritten)\n"
            "  --every N         only every Nth sweep (0, N, 2N, ...; default 1)\n"
            "  --vehicle FILE    vehicle file for base <- lidar (default vehicles/prius2017.yaml of the\n"
            "                    source tree).\n"
            "                    Sweeps written by import-scans name their frame in the sensor string:\n"
            "                    \"lidar:NAME\" (imported without --vehicle, GROUND_TRUTH is the LiDAR's\n"
            "                    pose): base <- lidar is the identity and --vehicle must not be given;\n"
            "                    \"VEHICLE:NAME\": the vehicle file must be that vehicle's\n"
            "  --quiet           no progress on stderr\n"
            "  -h, --help        this text\n"
            "Exit status 1 on a log that does not open, is damaged or holds no LIDAR_SCAN, a sweep that\n"
            "does not decode, a vehicle file that does not load or does not match, or an unwritable DIR.\n");
}

typedef struct {
    const char *log_path, *out_dir;
    long every;
    FILE *times, *gt;
    char *path_buf;
    size_t path_cap;
    float *buf;
    int buf_cap;
    pb_points_t pts;
    long long scans_seen, scans_written, points_written, gt_written;
    char first_sensor[128];
    int have_sensor;
} export_t;

static int make_dir(const char *path, pb_err_t *err)
{
    if (mkdir(path, 0777) == 0 || errno == EEXIST) {
        struct stat st;
        if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) return 0;
        return pb_err_set(err, "%s: exists and is not a folder", path);
    }
    return pb_err_set(err, "%s: cannot create folder: %s", path, strerror(errno));
}

static const char *join(export_t *e, const char *name)
{
    size_t n = strlen(e->out_dir) + strlen(name) + 2;
    if (n > e->path_cap) { e->path_cap = n; e->path_buf = realloc(e->path_buf, n); }
    snprintf(e->path_buf, n, "%s/%s", e->out_dir, name);
    return e->path_buf;
}

static void fprint_seconds(FILE *f, int64_t us)
{
    long long sec = (long long)(us / 1000000), frac = (long long)(us % 1000000);
    if (frac < 0) { frac += 1000000; sec -= 1; }
    fprintf(f, "%lld.%06lld", sec, frac);
}

static void on_pose(const portobello_pose_t *msg, const pb_transform_t *pose, void *user)
{
    export_t *e = user;
    for (int i = 0; i < 3; i++) if (!isfinite(pose->t[i])) return;
    for (int i = 0; i < 4; i++) if (!isfinite(pose->q[i])) return;
    fprint_seconds(e->gt, msg->utime);
    /* TUM: quaternion x y z w; pb_transform_t keeps w x y z */
    fprintf(e->gt, " %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", pose->t[0], pose->t[1], pose->t[2], pose->q[1],
            pose->q[2], pose->q[3], pose->q[0]);
    e->gt_written++;
}

static int on_scan(const pb_event_t *ev, void *user, pb_err_t *err)
{
    export_t *e = user;
    long long index = e->scans_seen++;
    portobello_lidar_scan_t s;
    if (portobello_lidar_scan_t_decode(ev->data, 0, ev->datalen, &s) < 0)
        return pb_err_set(err, "%s: byte %lld: LIDAR_SCAN does not decode as lidar_scan_t", e->log_path,
                          (long long)ev->offset);
    if (!e->have_sensor) {
        snprintf(e->first_sensor, sizeof e->first_sensor, "%s", s.sensor ? s.sensor : "");
        e->have_sensor = 1;
    }
    if (index % e->every != 0) { portobello_lidar_scan_t_decode_cleanup(&s); return 0; }
    pb_err_t serr;
    int n = pb_scan_points(&s, &e->pts, &serr);
    int64_t utime = s.utime;
    portobello_lidar_scan_t_decode_cleanup(&s);
    if (n < 0) return pb_err_set(err, "%s: byte %lld: LIDAR_SCAN %lld: %s", e->log_path, (long long)ev->offset, index,
                          serr.msg);
    if (4 * n > e->buf_cap) { e->buf_cap = 4 * n; e->buf = realloc(e->buf, sizeof(float) * e->buf_cap); }
    for (int i = 0; i < n; i++) {
        e->buf[4 * i + 0] = e->pts.x[i];
        e->buf[4 * i + 1] = e->pts.y[i];
        e->buf[4 * i + 2] = e->pts.z[i];
        e->buf[4 * i + 3] = (float)(e->pts.offset_us[i] * 1e-6);
    }
    char name[64];
    snprintf(name, sizeof name, "scans/%06lld.bin", index);
    const char *path = join(e, name);
    FILE *f = fopen(path, "wb");
    if (!f) return pb_err_set(err, "%s: cannot write: %s", path, strerror(errno));
    size_t w = n ? fwrite(e->buf, sizeof(float) * 4, n, f) : 0;
    if (fclose(f) != 0 || w != (size_t)n) return pb_err_set(err, "%s: write failed", path);
    fprint_seconds(e->times, utime);
    fputc('\n', e->times);
    e->scans_written++;
    e->points_written += n;
    return 0;
}

/* base <- lidar for the sweeps' frame (see usage). */
static int extrinsic(export_t *e, const char *vehicle_path, int vehicle_given, pb_transform_t *out, char *why,
                     size_t why_size, pb_err_t *err)
{
    const char *colon = strchr(e->first_sensor, ':');
    if (colon && colon - e->first_sensor == 5 && strncmp(e->first_sensor, "lidar", 5) == 0) {
        if (vehicle_given)
            return pb_err_set(err, "%s: LIDAR_SCAN sensor '%s': the scans were imported without --vehicle "
                              "(GROUND_TRUTH is the LiDAR's pose), so base <- lidar is the identity; drop --vehicle %s",
                              e->log_path, e->first_sensor, vehicle_path);
        *out = (pb_transform_t){{0, 0, 0}, {1, 0, 0, 0}};
        snprintf(why, why_size, "identity: LIDAR_SCAN sensor '%s' (imported without --vehicle; GROUND_TRUTH is "
                 "the LiDAR's pose)", e->first_sensor);
        return 0;
    }
    pb_vehicle_t veh;
    if (pb_vehicle_load(vehicle_path, &veh, err) != 0) return -1;
    if (colon) {
        size_t len = (size_t)(colon - e->first_sensor);
        if (strlen(veh.name) != len || strncmp(veh.name, e->first_sensor, len) != 0)
            return pb_err_set(err, "%s: LIDAR_SCAN sensor '%s': the scans are in the frame of vehicle '%.*s', but "
                              "%s is vehicle '%s': give --vehicle with the file the log was imported with",
                              e->log_path, e->first_sensor, (int)len, e->first_sensor, vehicle_path, veh.name);
    }
    *out = veh.base_from_lidar;
    snprintf(why, why_size, "vehicle file %s (vehicle '%s'); LIDAR_SCAN sensor '%s'", vehicle_path, veh.name,
             e->first_sensor);
    return 0;
}

static int write_extrinsic(export_t *e, const pb_transform_t *b, const char *why, pb_err_t *err)
{
    const char *path = join(e, "base_from_lidar.txt");
    FILE *f = fopen(path, "w");
    if (!f) return pb_err_set(err, "%s: cannot write: %s", path, strerror(errno));
    double R[9];
    pb_quat_to_matrix(b->q, R);
    fprintf(f, "# base <- lidar (p_base = T * p_lidar), 4x4 row-major, metres\n# from %s\n", why);
    for (int r = 0; r < 3; r++)
        fprintf(f, "%.9f %.9f %.9f %.9f\n", R[3 * r], R[3 * r + 1], R[3 * r + 2], b->t[r]);
    fprintf(f, "0 0 0 1\n");
    if (fclose(f) != 0) return pb_err_set(err, "%s: write failed", path);
    return 0;
}

int main(int argc, char **argv)
{
    export_t e = {.every = 1};
    const char *vehicle_path = NULL;
    int quiet = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &e.log_path), PB_OPT_REQUIRED("out", &e.out_dir),
        PB_OPT_LONG("every", &e.every, 1, 1000000), PB_OPT_STRING("vehicle", &vehicle_path),
        PB_OPT_FLAG("quiet", &quiet, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("scan-export", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    int vehicle_given = vehicle_path != NULL;
    if (!vehicle_path) vehicle_path = DEFAULT_VEHICLE;

    pb_err_t err;
    int rc = 1;
    pb_log_t *log = pb_log_open_read(e.log_path, &err);
    if (!log) { fprintf(stderr, "scan-export: %s\n", err.msg); return 1; }
    char *times_path = NULL, *gt_path = NULL;
    if (make_dir(e.out_dir, &err) != 0 || make_dir(join(&e, "scans"), &err) != 0) {
        fprintf(stderr, "scan-export: %s\n", err.msg);
        goto done;
    }
    times_path = strdup(join(&e, "times.txt"));
    gt_path = strdup(join(&e, "ground_truth.tum"));
    e.times = fopen(times_path, "w");
    e.gt = fopen(gt_path, "w");
    if (!e.times || !e.gt) {
        fprintf(stderr, "scan-export: %s: cannot write: %s\n", !e.times ? times_path : gt_path, strerror(errno));
        goto done;
    }
    /* one pass in log order; progress by bytes read */
    pb_progress_t prog;
    pb_progress_start(&prog, "scan-export", pb_log_size(log), quiet);
    pb_event_t ev;
    int r;
    while ((r = pb_log_next(log, &ev, &err)) == 1) {
        if (strcmp(ev.channel, "LIDAR_SCAN") == 0) {
            if (on_scan(&ev, &e, &err) != 0) { r = -1; break; }
            pb_progress_update(&prog, pb_log_position(log));
        } else if (strcmp(ev.channel, "GROUND_TRUTH") == 0) {
            portobello_pose_t msg;
            pb_transform_t pose;
            if (pb_log_pose(&ev, &msg, &pose, &err) != 0) { r = -1; pb_err_prefix(&err, "%s", e.log_path); break; }
            on_pose(&msg, &pose, &e);
        }
    }
    if (r == 0) pb_progress_finish(&prog);
    int times_bad = fclose(e.times) != 0, gt_bad = fclose(e.gt) != 0;
    e.times = e.gt = NULL;
    if (r != 0) { fprintf(stderr, "scan-export: %s\n", err.msg); goto done; }
    if (times_bad || gt_bad) {
        fprintf(stderr, "scan-export: %s: write failed\n", times_bad ? times_path : gt_path);
        goto done;
    }
    if (e.scans_seen == 0) { fprintf(stderr, "scan-export: %s: no LIDAR_SCAN in the log\n", e.log_path); goto done; }
    if (e.gt_written == 0) remove(gt_path);

    pb_transform_t b;
    char why[1024];
    if (extrinsic(&e, vehicle_path, vehicle_given, &b, why, sizeof why, &err) != 0 ||
        write_extrinsic(&e, &b, why, &err) != 0) {
        fprintf(stderr, "scan-export: %s\n", err.msg);
        goto done;
    }
    fprintf(stderr, "scan-export: %lld of %lld sweeps (%lld points) and %lld GROUND_TRUTH poses written to %s\n",
            e.scans_written, e.scans_seen, e.points_written, e.gt_written, e.out_dir);
    if (e.gt_written == 0) fprintf(stderr, "scan-export: note: %s has no GROUND_TRUTH; no ground_truth.tum\n", e.log_path);
    rc = 0;
done:
    pb_log_close(log, NULL);
    if (e.times) fclose(e.times);
    if (e.gt) fclose(e.gt);
    free(times_path);
    free(gt_path);
    free(e.buf);
    free(e.path_buf);
    pb_points_free(&e.pts);
    return rc;
}
