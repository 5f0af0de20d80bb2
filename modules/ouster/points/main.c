/* ouster-points: the points of LIDAR_SCAN messages of a log as CSV, computed by
 * common/pb_scan (the one implementation of the range-image model), so that a driver's
 * output can be checked point by point against reference xyz. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_log.h"
#include "pb_opt.h"
#include "pb_scan.h"
#include "portobello_lidar_scan_t.h"

static void usage(FILE *f)
{
    fprintf(f,
        "usage: ouster-points --in LOG.lcm [--channel LIDAR_SCAN] [--scan N]\n"
        "Prints the valid points of each LIDAR_SCAN (or only the N-th, 0-based) as CSV:\n"
        "  scan,seq,row,col,x_m,y_m,z_m,reflectivity,offset_us\n"
        "x, y, z in the lidar frame from common/pb_scan; row/col are the range-image pixel\n"
        "(range-image form) or -1,-1 (point form).\n");
}

int main(int argc, char **argv)
{
    const char *in = NULL, *channel = "LIDAR_SCAN";
    long want = -1;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("in", &in), PB_OPT_STRING("channel", &channel), PB_OPT_LONG("scan", &want, 0, 1L << 40),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("ouster-points", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    pb_log_t *log = pb_log_open_read(in, &err);
    if (!log) { fprintf(stderr, "ouster-points: %s\n", err.msg); return 1; }
    pb_points_t pts = { 0 };
    pb_event_t ev;
    int rc, status = 0;
    long k = -1;
    printf("scan,seq,row,col,x_m,y_m,z_m,reflectivity,offset_us\n");
    while ((rc = pb_log_next(log, &ev, &err)) == 1) {
        if (strcmp(ev.channel, channel) != 0) continue;
        k++;
        if (want >= 0 && k != want) continue;
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) {
            fprintf(stderr, "ouster-points: %s: event %lld does not decode\n", in, (long long)ev.eventnum);
            status = 1;
            continue;
        }
        int n = pb_scan_points(&s, &pts, &err);
        if (n < 0) {
            fprintf(stderr, "ouster-points: %s: event %lld: %s\n", in, (long long)ev.eventnum, err.msg);
            status = 1;
        } else {
            /* pb_scan walks columns, then rows, skipping pixels without a return */
            int i = 0;
            for (int col = 0; s.npixels > 0 && col < s.cols; col++)
                for (int row = 0; row < s.rows && i < n; row++) {
                    if (s.range_mm[row * s.cols + col] <= 0) continue;
                    printf("%ld,%d,%d,%d,%.6f,%.6f,%.6f,%.0f,%d\n", k, s.seq, row, col, pts.x[i], pts.y[i], pts.z[i],
                           pts.intensity[i], pts.offset_us[i]);
                    i++;
                }
            for (; s.npixels == 0 && i < n; i++)
                printf("%ld,%d,-1,-1,%.6f,%.6f,%.6f,%g,%d\n", k, s.seq, pts.x[i], pts.y[i], pts.z[i], pts.intensity[i],
                       pts.offset_us[i]);
        }
        portobello_lidar_scan_t_decode_cleanup(&s);
    }
    if (rc < 0) { fprintf(stderr, "ouster-points: %s\n", err.msg); status = 1; }
    pb_points_free(&pts);
    pb_log_close(log, NULL);
    return status;
}
