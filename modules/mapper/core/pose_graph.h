/* pose_graph: what the mapper's two pose graphs share (loops.cpp: odometry and loop edges;
 * anchor.cpp: the trajectory's steps and GNSS fixes): the relative-pose edge for Ceres and
 * the moving of every sweep with the corrections solved at a few nodes.
 *
 * Frames: poses are map <- base. Pure: no I/O, no clock. Ownership: plain values. */
#ifndef PB_MAPPER_POSE_GRAPH_H
#define PB_MAPPER_POSE_GRAPH_H

#include <stdint.h>
#include <vector>
#include <Eigen/Core>
#include <Eigen/Geometry>

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

/* Moves poses (utime[i], poses[i], in time order) by the corrections solved at the nodes
 * (node_utime in time order; a node's correction = solved * before^-1): each pose takes its
 * node's (the last at or before it), blended towards the next node's by time (rotation
 * slerped, translation linear). Poses before the first node take the first's. */
void pb_pose_graph_apply(const std::vector<int64_t> &node_utime, const std::vector<Eigen::Isometry3d> &before,
                         const std::vector<Eigen::Isometry3d> &solved, const std::vector<int64_t> &utime,
                         std::vector<Eigen::Isometry3d> *poses);

#endif
