/* places: place recognition in the prior map, for a start with no prior at all.
 *
 * A Scan-Context-like descriptor (after Kim and Kim, "Scan Context", IROS 2018): around
 * a place, a polar grid of PLACE_RINGS rings x PLACE_SECTORS sectors holds the highest
 * structure above the ground in each bin. The map's descriptors are computed from the
 * map itself at every free ground spot on a grid; a sweep's from its points. Occlusion
 * is modelled on both sides alike: along each sector, bins behind the first tall
 * structure are unknown (a sweep cannot see through a wall; the map has what is behind
 * it), and only bins known on both sides are compared.
 *
 * Query: a rotation-invariant ring key (per ring, the mean height of its known bins)
 * shortlists places; the full descriptors are then compared under every sector shift,
 * which also gives the yaw. The caller verifies the best few by registration and the
 * structure test: a descriptor only proposes. Two sweeps' descriptors compare the same
 * way (places_compare): the mapper's loop closure finds places it passed before so.
 *
 * Pure: no I/O, no clocks. Ownership: places_build returns an object the caller frees
 * with places_destroy; the map is only read while building. */
#ifndef LOC_PLACES_H
#define LOC_PLACES_H

#include <cstddef>
#include <cstdint>
#include <vector>

#include "regmap.h"

namespace pb_loc {

enum { PLACE_RINGS = 20, PLACE_SECTORS = 60 };

struct places_config_t {
    double ring_m = 2.0;          /* ring width: the grid reaches PLACE_RINGS * ring_m */
    double place_step_m = 1.0;    /* places every this many metres of free ground (a 3 m
                                   * step leaves the truth up to 2.1 m from a place, and the
                                   * inner rings differ: see shortlist) */
    double separation_m = 3.0;    /* a query's answers lie this far apart at least (the
                                   * neighbours of a place are that place to a search; a
                                   * query setting, not stored with the places) */
    double min_height_m = 0.7;    /* structure starts this high above the ground */
    double tall_m = 2.5;          /* a bin this high hides the bins behind it */
    double clip_m = 5.0;          /* heights are clipped here (the sweep sees little higher nearby) */
    double car_clearance_m = 2.0; /* a place needs no structure up to this height at its spot */
    int shortlist = 5400;         /* places compared in full after the ring key (a query
                                   * setting, not stored with the places). MulRan, 83
                                   * keyframes of each split against the other's map, the
                                   * true place among the best 16: 45 / 38 at a 3 m step and
                                   * 300, 55 / 55 at 1 m and 2700, 58 / 56 at 5400 (best 8:
                                   * 50 / 50 -> 55 / 54); every place in full gives 58 / 57
                                   * but fewer true places first (38 / 35 against 43 / 40):
                                   * the ring key also keeps look-alikes out */
};

/* One descriptor: height (m, 0 = free) per bin, -1 unknown (hidden). */
struct place_desc_t {
    float h[PLACE_RINGS][PLACE_SECTORS];
    float ring_key[PLACE_RINGS];      /* mean height per ring over its known bins / clip */
};

struct place_match_t {
    double x, y, z;      /* the place: map position of the ground spot */
    double yaw;          /* base yaw in map that aligns the sweep's descriptor */
    double distance;     /* descriptor distance, 0..1 (smaller is more alike) */
};

typedef struct places places_t;

/* Builds the descriptors of every free ground spot of the map. NULL if the map has no
 * ground. The columns are held in blocks where the map has cells, so memory follows the
 * map's area, not its bounding box. */
places_t *places_build(const pb_regmap_t *map, const places_config_t &cfg);

/* The same from the map's cells given a part at a time (pb_regmap_cells' points and
 * ground flags, e.g. tile by tile): every part to _extent, then every part to _ground,
 * then every part to _structure; _finish returns what places_build would (NULL: no
 * ground) and frees the builder. Any order of the parts gives the same places. */
typedef struct places_builder places_builder_t;
places_builder_t *places_builder_new(const places_config_t &cfg);
void places_builder_extent(places_builder_t *b, const float *xyz, size_t n);
void places_builder_ground(places_builder_t *b, const float *xyz, const uint8_t *ground, size_t n);
void places_builder_structure(places_builder_t *b, const float *xyz, const uint8_t *ground, size_t n);
places_t *places_builder_finish(places_builder_t *b);
/* Frees a builder not finished (an error on the way). */
void places_builder_destroy(places_builder_t *b);
void places_destroy(places_t *p);
size_t places_count(const places_t *p);

/* Serialises the places (out replaced), to be stored with the map (core/map_tiles):
 * a start with no prior then needs neither the whole map nor the build. */
void places_encode(const places_t *p, std::vector<uint8_t> *out);
/* Reads places_encode's bytes; NULL with msg (one line, byte offset named) when they are
 * damaged. */
places_t *places_decode(const uint8_t *bytes, size_t n, char *msg, size_t msg_len);

/* The descriptor of a sweep (points in base, metres; base z = 0 on the ground), with
 * the places' settings or with the given ones (sweeps compared with each other). */
void places_describe(const places_t *p, const float *xyz, size_t n, place_desc_t *d);
void places_describe(const places_config_t &cfg, const float *xyz, size_t n, place_desc_t *d);

/* Descriptor distance of a to b under the best sector shift, 0..1 (smaller is more
 * alike; 1 when too few bins are known on both sides); *yaw gets the yaw of a's frame in
 * b's frame that the shift stands for (a multiple of 360 / PLACE_SECTORS degrees). */
double places_compare(const places_config_t &cfg, const place_desc_t &a, const place_desc_t &b, double *yaw);

/* The k most alike places, best first. */
void places_query(const places_t *p, const place_desc_t &d, int k, std::vector<place_match_t> *out);

} // namespace pb_loc
#endif
