/* summary: what a drive log holds, per channel, and how the vehicle moved.
 * Pure core: fed decoded facts with their message times, no I/O except
 * summary_print. Ownership: summary_t is a plain struct the caller owns. */
#ifndef SUMMARY_H
#define SUMMARY_H

#include <stdint.h>
#include <stdio.h>

#define SUMMARY_MAX_CHANNELS 64

typedef struct {
    char name[64];
    int64_t count, bytes, first_utime, last_utime;
} summary_channel_t;

typedef struct {
    summary_channel_t channels[SUMMARY_MAX_CHANNELS];
    int nchannels;
    /* ground truth (or any pose channel chosen) */
    int64_t poses;
    double distance_m, max_speed_mps, last_pos[3];
    int64_t stopped_since, stops;       /* stops: standstill of 1 s or more */
    int stop_counted;
    int64_t last_pose_utime;
    double speed_sum;
    /* LiDAR */
    int64_t scans, scan_points, scan_pixels;
    /* CAN */
    int64_t can_frames, can_ids[8][2];  /* [id, count] for the first 8 ids seen */
    int ncan_ids;
    /* GNSS */
    int64_t fixes;
    double gnss_err_sum;                /* vs ground truth, when both present */
    int64_t gnss_err_n;
} summary_t;

void summary_init(summary_t *s);
/* Any message: counted on its channel with its message utime. */
void summary_message(summary_t *s, const char *channel, int64_t utime, int32_t bytes);
void summary_pose(summary_t *s, int64_t utime, const double pos[3], const double vel[3]);
void summary_scan(summary_t *s, int32_t points, int32_t pixels);
void summary_can(summary_t *s, int32_t id);
void summary_print(const summary_t *s, FILE *f);

#endif
