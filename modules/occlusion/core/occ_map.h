/* occ_map: what the LiDAR sees around the car, in the map frame, and what it hides
 * from an eye.
 *
 * The store is OctoMap, two trees over one rolling window around the car:
 *  - `fine` (0.2 m): occupancy of real objects above the ground. Each sweep's
 *    endpoints are hits (one update per voxel, lazily); every occupied voxel in
 *    view is then checked against the sweep itself, binned by direction: where
 *    the beams around it went on past it (by clear_margin_m), it gets a miss, so
 *    a bus that drove on is gone after one or two sweeps. This clears only the
 *    voxels that hold something, instead of tracing every beam through the tree.
 *    Within a voxel, what its returns stand for is kept as 5 cm columns up to a top (the
 *    highest return plus a part of the ring gap): this sweep's for the voxels it hit (and
 *    the half column gap around each return, into the neighbouring voxels), and for
 *    occupied voxels not hit this sweep the union of the sweeps that hit them.
 *  - `observed` (0.8 m): space the LiDAR has looked through or at (every
 *    observed_ray_stride-th beam traced): what is not in it is unknown, not free.
 * Ground returns (below the local ground + ground_clearance_m, from a 1 m grid of
 * the lowest return) are not occluders: the eye looks along the ground at feet.
 * Returns of the lowest beams above the ground within fill_radius_m mark an object
 * reaching under the LiDAR's view (a car alongside): its column down to the ground
 * counts as occupied for this sweep's queries only (not written to the trees).
 * Blocks of 6.4 m farther than window_m from the car are deleted from both trees.
 *
 * Queries walk the observed-size cells from the eye to a sample (skipping the car's
 * own box), and the fine voxels only in cells that may hold an occupied one, through
 * bitmap indexes (occupied voxels confirmed in the tree): hidden if an occupied voxel
 * lies before the sample, else unknown if any part of the way was never observed,
 * else visible.
 *
 * Pure: no I/O, no clocks. Ownership: occ_map_create returns a map freed with
 * occ_map_destroy; inputs are only read during the calls. */
#ifndef OCC_MAP_H
#define OCC_MAP_H

#include <stdint.h>

struct occ_config_t {
    double resolution = 0.2;          /* fine voxel edge, m */
    double observed_resolution = 0.8; /* observed-space voxel edge, m (a power of 2 times resolution) */
    double range_m = 45.0;            /* returns and queries within this distance of the sensor / eye */
    double window_m = 46.0;           /* rolling window: blocks whose centre is farther from the car go */
    double ground_clearance_m = 0.25; /* returns this close to the local ground are ground */
    double clear_margin_m = 0.4;      /* a beam that ends this far past a voxel clears it */
    int point_stride = 1;             /* every Nth return per sweep for hits and ground (alternating) */
    int clear_bins_el = 1, clear_bins_az = 0;  /* a voxel is cleared by the beams of its direction bin and this many bins either side (at least as many as reach the nearest beam of a sensor with wider gaps) */
    int observed_ray_stride = 8;      /* every Nth return's beam marks observed space (the next N-1 sweeps trace the others) */
    double prob_hit = 0.7, prob_miss = 0.1, clamp_min = 0.12, clamp_max = 0.88;  /* one clear miss frees any voxel */
    double fill_radius_m = 10.0;      /* returns of the lowest beams this close (horizontally) are checked for objects reaching under the view */
    double fill_elevation_tol_rad = 0.021;  /* "lowest beams": within 1.2 deg of the sweep's least elevation */
    double beam_gap_rad = 0.0092;     /* largest angle between neighbouring rings (0.52 deg): how far above a voxel's highest return its object may reach (for sweeps that do not say their own) */
    double beam_gap_az_rad = 0.00614; /* angle between neighbouring columns (2 pi / 1024): a return's sub-cells grow by half of it, into neighbouring voxels too (idem) */
    double top_gap_fraction = 0.25;   /* a voxel's object ends this fraction of the ring gap above its highest return (where the voxel above holds nothing) */
    double stop_short_m = 0.2;        /* eye rays stop this far before the sample (the agent's own spot) */
    /* the car's own box in base (the eye looks out through it): x from, x to, half width, height */
    double ego_x0 = -1.04, ego_x1 = 3.50, ego_half_width = 0.88, ego_height = 1.47;
};

/* One sweep in the map frame: endpoints and, per endpoint, the index of its sensor origin. */
struct occ_sweep_t {
    int n;
    const float *x, *y, *z;
    const uint16_t *origin_index;     /* into origins */
    int norigins;
    const double (*origins)[3];       /* sensor positions during the sweep, map */
    double mid_origin[3];             /* sensor at mid sweep, map: the view the sweep is binned in */
    double mid_rot[9];                /* map <- sensor at mid sweep, row-major */
    double car[3];                    /* base origin, map: the window's centre */
    double ring_gap_rad, col_gap_rad; /* the sensor's beam gaps (pb_scan_beam_gaps); 0: the config's beam_gap_rad, beam_gap_az_rad */
};

struct occ_integrate_stats_t {
    int points, ground, hit_voxels, cleared, occupied_checked, observed_new, blocks_deleted, filled;
};

enum { OCC_VISIBLE = 0, OCC_HIDDEN = 1, OCC_UNKNOWN = 2 };

struct occ_map_t;

occ_map_t *occ_map_create(const occ_config_t *cfg);
void occ_map_destroy(occ_map_t *m);

/* Integrates one sweep (returns beyond range_m or not finite are skipped). */
void occ_map_integrate(occ_map_t *m, const occ_sweep_t *sw, occ_integrate_stats_t *st);

/* States of n samples seen from eye (map); base_pos/base_yaw place the car's own box.
 * occluder_m: distance from the eye to the first occupied voxel (hidden), else NaN. */
void occ_map_query(const occ_map_t *m, const double eye[3], const double base_pos[3], double base_yaw,
                   const float *x, const float *y, const float *z, int n, int8_t *state, float *occluder_m);

/* Distance along the eye ray (d unit) at which it leaves the car's own box; 0 if the eye is outside it. */
double occ_map_ego_exit(const occ_map_t *m, const double eye[3], const double d[3], const double base_pos[3], double base_yaw);

/* Forgets everything (e.g. after the pose jumped). */
void occ_map_clear(occ_map_t *m);

/* Size of the store: leaves of both trees and their memory (OctoMap's own count), bytes. */
void occ_map_size(const occ_map_t *m, int64_t *leaves, int64_t *bytes);

#endif
