/* pose_files: the text files import-scans reads besides the scans: poses (KITTI 3x4,
 * TUM, or a time and a 3x4), scan times (one a line) and a KITTI calib's Tr line.
 * Numbers are separated by white space or commas; '#' lines are comments (poses,
 * times). A time is seconds (up to 12 integer digits and any decimals), or an
 * integer of 16 digits (microseconds) or 19 (nanoseconds).
 * Each reader returns 0, or -1 with err naming FILE:LINE and what is wrong. */
#ifndef IMPORT_SCANS_POSE_FILES_H
#define IMPORT_SCANS_POSE_FILES_H

#include <stdint.h>
#include <string>
#include <vector>
#include <Eigen/Geometry>
#include "pb_err.h"

enum PoseFormat { FMT_NONE, FMT_KITTI, FMT_TUM, FMT_KITTI_TIMED };

/* "KITTI (12)", "TUM (8)" or "timed KITTI (13)". */
const char *format_name(PoseFormat f);

/* Poses map <- frame, appended; times (microseconds, increasing) for TUM and timed KITTI. */
int read_poses(const char *path, std::vector<Eigen::Isometry3d> &poses, std::vector<int64_t> &times,
               PoseFormat *fmt, pb_err_t *err);

/* The calib's Tr (velodyne -> camera). */
int read_calib_tr(const char *path, Eigen::Isometry3d *Tr, pb_err_t *err);

/* A time as the files hold it (see above) -> microseconds. Returns 0 or -1. */
int parse_time_us(const std::string &s, int64_t *out);

/* One time a line, microseconds, appended. */
int read_times(const char *path, std::vector<int64_t> &times, pb_err_t *err);

#endif
