/* picture: the mapper's report as a top-down PNG (libpng): the map's points (grey, darker
 * where denser), the trajectory before loop closure (orange) and after (blue), the loops
 * (green, from the earlier pass's keyframe to the later one), the GNSS fixes (red dots),
 * and the points carved out of the map as moving objects (magenta: to inspect what went;
 * those that went as objects the views saw through in violet, drawn larger).
 * North is up when the map is geo-referenced (east-north-up); one pixel is `m_per_px`.
 * Shell-side: it writes the file. */
#ifndef PB_MAPPER_PICTURE_H
#define PB_MAPPER_PICTURE_H

#include <vector>
#include <Eigen/Core>
#include "pb_err.h"

typedef struct {
    std::vector<Eigen::Vector3d> before, after;   /* trajectory positions, map frame (NaN between drives) */
    std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> loops;
    std::vector<Eigen::Vector3d> fixes;           /* GNSS fixes in the map frame (may be empty) */
    std::vector<float> removed;                   /* carved points, x y z interleaved, map frame */
    std::vector<float> objects;                   /* of those, the ones carved as objects seen through */
} pb_picture_layers_t;

/* The picture is drawn as the map is written, a part at a time: begin (the extent comes
 * from the trajectory; NULL when layers->after is empty), add the map's points (x, y, z
 * floats, `stride` floats apart) in parts, then write it to png_path with the layers
 * (*m_per_px gets the scale; 0 or -1, err set) and free it with end (NULL is a no-op). */
typedef struct pb_picture pb_picture_t;
pb_picture_t *pb_picture_begin(const pb_picture_layers_t *layers);
void pb_picture_add(pb_picture_t *p, const float *xyz, size_t n, size_t stride);
int pb_picture_write(pb_picture_t *p, const pb_picture_layers_t *layers, const char *png_path, double *m_per_px,
                     pb_err_t *err);
void pb_picture_end(pb_picture_t *p);

#endif
