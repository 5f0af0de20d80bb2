/* scan_files: the scan files import-scans reads, into one Scan each: KITTI-style .bin
 * (float32 fields, --bin-fields) and PCD (through PCL), and point times from azimuth for
 * raw sweeps that carry none. Each reader returns 0, or -1 with err naming FILE and,
 * for .bin, the byte where it went wrong. */
#ifndef IMPORT_SCANS_SCAN_FILES_H
#define IMPORT_SCANS_SCAN_FILES_H

#include <stdint.h>
#include <string>
#include <vector>
#include "pb_err.h"

/* One scan's points in the LiDAR frame; offset_us and ring only when has_time / has_ring. */
struct Scan {
    std::vector<float> x, y, z, intensity;
    std::vector<int32_t> offset_us;
    std::vector<uint8_t> ring;
    bool has_time = false, has_ring = false;
    long dropped = 0;
    void clear()
    {
        x.clear(); y.clear(); z.clear(); intensity.clear(); offset_us.clear(); ring.clear();
        has_time = has_ring = false;
        dropped = 0;
    }
};

/* The record of a .bin point: float32 fields in file order (--bin-fields); an index per
 * field, -1 when absent. The default is KITTI's x y z i. */
struct BinLayout {
    int nfields = 4;
    int x = 0, y = 1, z = 2, i = 3, ring = -1, t = -1;   // field index, -1: absent
};

/* Parses a --bin-fields list: names from x y z i ring t (seconds after the scan's time)
 * and _ (a field skipped), comma-separated; x, y and z needed. */
int parse_bin_fields(const char *list, BinLayout *out, pb_err_t *err);

/* Reads a .bin scan of records L. With check_layout, a file whose points would be
 * neighbours in space read with another record size (3-8 floats) is an error naming it:
 * a spinning LiDAR writes its points in firing order, and read with the wrong size x y z
 * come from other fields. A point time beyond a second of the scan's is an error (a
 * float32 cannot hold a UNIX time to the microsecond). */
int read_bin(const std::string &path, const BinLayout &L, bool check_layout, Scan &s, pb_err_t *err);

/* Reads a PCD scan: fields x y z, optionally intensity (or i), t (ns) or time (s) after
 * the sweep's start, ring. */
int read_pcd(const std::string &path, Scan &s, pb_err_t *err);

/* Gives a scan without point times each point's time from its azimuth: the LiDAR turns
 * once in sweep_us, clockwise seen from above (ccw false: Velodyne, Ouster) or not, from
 * seam_rad (the azimuth from x toward y where the sweep starts, at the scan's time). With
 * seam_rad NAN the scan must be in firing order (a median step between neighbours under 5
 * degrees, and the small steps adding up to 3/4 of a turn or more the way ccw says; a
 * column's beams may step either way by their azimuth offsets, the columns advance one
 * way), and the sweep starts at its first point; else it is an error saying which. */
int times_from_azimuth(const std::string &path, Scan &s, bool ccw, double seam_rad, double sweep_us, pb_err_t *err);

#endif
