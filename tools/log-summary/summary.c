#include "summary.h"

#include <math.h>
#include <string.h>

void summary_init(summary_t *s)
{
    memset(s, 0, sizeof *s);
    s->stopped_since = -1;
}

void summary_message(summary_t *s, const char *channel, int64_t utime, int32_t bytes)
{
    summary_channel_t *c = NULL;
    for (int i = 0; i < s->nchannels; i++)
        if (strcmp(s->channels[i].name, channel) == 0) c = &s->channels[i];
    if (!c) {
        if (s->nchannels == SUMMARY_MAX_CHANNELS) return;
        c = &s->channels[s->nchannels++];
        snprintf(c->name, sizeof c->name, "%s", channel);
        c->first_utime = utime;
    }
    c->count++;
    c->bytes += bytes;
    if (utime < c->first_utime) c->first_utime = utime;
    if (utime > c->last_utime) c->last_utime = utime;
}

void summary_pose(summary_t *s, int64_t utime, const double pos[3], const double vel[3])
{
    double speed = sqrt(vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2]);
    if (s->poses > 0) {
        double dx = pos[0] - s->last_pos[0], dy = pos[1] - s->last_pos[1], dz = pos[2] - s->last_pos[2];
        s->distance_m += sqrt(dx * dx + dy * dy + dz * dz);
    }
    /* A stop is a standstill (< 0.1 m/s) that lasts at least 1 s. */
    if (speed < 0.1) {
        if (s->stopped_since < 0) { s->stopped_since = utime; s->stop_counted = 0; }
        if (!s->stop_counted && utime - s->stopped_since >= 1000000) { s->stops++; s->stop_counted = 1; }
    } else {
        s->stopped_since = -1;
    }
    if (speed > s->max_speed_mps) s->max_speed_mps = speed;
    s->speed_sum += speed;
    memcpy(s->last_pos, pos, sizeof s->last_pos);
    s->last_pose_utime = utime;
    s->poses++;
}

void summary_scan(summary_t *s, int32_t points, int32_t pixels)
{
    s->scans++;
    s->scan_points += points;
    s->scan_pixels += pixels;
}

void summary_can(summary_t *s, int32_t id)
{
    s->can_frames++;
    for (int i = 0; i < s->ncan_ids; i++)
        if (s->can_ids[i][0] == id) { s->can_ids[i][1]++; return; }
    if (s->ncan_ids < 8) { s->can_ids[s->ncan_ids][0] = id; s->can_ids[s->ncan_ids][1] = 1; s->ncan_ids++; }
}

void summary_print(const summary_t *s, FILE *f)
{
    fprintf(f, "%-16s %9s %9s %11s %10s\n", "channel", "messages", "rate Hz", "MB", "span s");
    for (int i = 0; i < s->nchannels; i++) {
        const summary_channel_t *c = &s->channels[i];
        double span = (c->last_utime - c->first_utime) * 1e-6;
        double rate = span > 0 ? (c->count - 1) / span : 0;
        fprintf(f, "%-16s %9lld %9.1f %11.2f %10.2f\n", c->name, (long long)c->count, rate, c->bytes / 1e6, span);
    }
    if (s->poses) {
        fprintf(f, "\nvehicle: %.1f m driven, mean speed %.2f m/s, max %.2f m/s, %lld stops of 1 s or more\n",
                s->distance_m, s->speed_sum / s->poses, s->max_speed_mps, (long long)s->stops);
    }
    if (s->scans)
        fprintf(f, "lidar: %lld scans, %.0f returns per scan (%.1f%% of pixels)\n", (long long)s->scans,
                (double)s->scan_points / s->scans, s->scan_pixels ? 100.0 * s->scan_points / s->scan_pixels : 100.0);
    if (s->can_frames) {
        fprintf(f, "can: %lld frames;", (long long)s->can_frames);
        for (int i = 0; i < s->ncan_ids; i++)
            fprintf(f, " 0x%03llX x %lld", (long long)s->can_ids[i][0], (long long)s->can_ids[i][1]);
        fprintf(f, "\n");
    }
}
