/* pose_graph: what the mapper's two pose graphs share (loops.cpp: odometry and loop edges;
 * anchor.cpp: the trajectory's steps and GNSS fixes): the nodes as Ceres parameters, the
 * relative-pose edge, the solve, and the moving of every sweep with the corrections solved
 * at the nodes.
 *
 * Frames: poses are map <- base. Pure: no I/O, no clock; deterministic (one thread).
 * Ownership: a pb_pose_graph owns its problem and the cost functions added through it; a
 * loss function given to its problem stays the caller's (it must outlive the graph). */
#ifndef PB_MAPPER_POSE_GRAPH_H
#define PB_MAPPER_POSE_GRAPH_H

#include <stdint.h>
#include <array>
#include <vector>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <ceres/ceres.h>
#include "pb_err.h"

/* The relative pose b in a's frame against a measured one: translation error in a's frame
 * and twice the vector part of the rotation error quaternion (small angles: the angle),
 * weighted by the edge's square-root information. Parameters: qa (x y z w), ta, qb, tb. */
struct pb_relative_pose_error {
    Eigen::Vector3d t_ab;
    Eigen::Quaterniond q_ab;
    Eigen::Matrix<double, 6, 6> sqrt_info;

    template <class T>
    bool operator()(const T *qa_p, const T *ta_p, const T *qb_p, const T *tb_p, T *res) const
    {
        Eigen::Map<const Eigen::Quaternion<T>> qa(qa_p), qb(qb_p);
        Eigen::Map<const Eigen::Matrix<T, 3, 1>> ta(ta_p), tb(tb_p);
        Eigen::Quaternion<T> qa_inv = qa.conjugate();
        Eigen::Matrix<T, 3, 1> t_est = qa_inv * (tb - ta);
        Eigen::Quaternion<T> dq = q_ab.template cast<T>().conjugate() * (qa_inv * qb);
        Eigen::Map<Eigen::Matrix<T, 6, 1>> r(res);
        r.template head<3>() = t_est - t_ab.template cast<T>();
        r.template tail<3>() = T(2.0) * dq.vec();
        r.applyOnTheLeft(sqrt_info.template cast<T>());
        return true;
    }
};

/* Diagonal square-root information of an edge: sigma_m on each axis, sigma_rad on each angle. */
inline Eigen::Matrix<double, 6, 6> pb_sqrt_info(double sigma_m, double sigma_rad)
{
    Eigen::Matrix<double, 6, 1> d;
    d << Eigen::Vector3d::Constant(1 / sigma_m), Eigen::Vector3d::Constant(1 / sigma_rad);
    return d.asDiagonal();
}

/* The nodes (q: x y z w, t) start at the given poses; edges and other residuals go into
 * `problem` on q[k].data(), t[k].data(). */
struct pb_pose_graph {
    std::vector<std::array<double, 4>> q;
    std::vector<std::array<double, 3>> t;
    ceres::EigenQuaternionManifold quat;
    ceres::Problem problem;

    explicit pb_pose_graph(const std::vector<Eigen::Isometry3d> &poses);
    /* An edge: node b in node a's frame is rel, with this square-root information. */
    void add_edge(size_t a, size_t b, const Eigen::Isometry3d &rel, const Eigen::Matrix<double, 6, 6> &sqrt_info);
    /* Solves (sparse normal Cholesky, one thread, up to 100 iterations), the rotations on
     * their manifold; *iterations grows by the solver's. Returns 0, or -1 with err naming
     * `what` when the solution is not usable. */
    int solve(const char *what, int *iterations, pb_err_t *err);
    /* The nodes' poses now. */
    std::vector<Eigen::Isometry3d> poses() const;
};

/* Moves poses (utime[i], poses[i], in time order) by the corrections solved at the nodes
 * (node_utime in time order; a node's correction = solved * before^-1): each pose takes its
 * node's (the last at or before it), blended towards the next node's by time (rotation
 * slerped, translation linear). Poses before the first node take the first's. */
void pb_pose_graph_apply(const std::vector<int64_t> &node_utime, const std::vector<Eigen::Isometry3d> &before,
                         const std::vector<Eigen::Isometry3d> &solved, const std::vector<int64_t> &utime,
                         std::vector<Eigen::Isometry3d> *poses);

#endif
