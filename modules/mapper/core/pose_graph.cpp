/* pose_graph: see pose_graph.h. */
#include "pose_graph.h"

#include <algorithm>

void pb_pose_graph_apply(const std::vector<int64_t> &node_utime, const std::vector<Eigen::Isometry3d> &before,
                         const std::vector<Eigen::Isometry3d> &solved, const std::vector<int64_t> &utime,
                         std::vector<Eigen::Isometry3d> *poses)
{
    const size_t n = node_utime.size();
    if (n == 0) return;
    std::vector<Eigen::Isometry3d> C(n);
    for (size_t k = 0; k < n; k++) C[k] = solved[k] * before[k].inverse();
    size_t a = 0;
    for (size_t i = 0; i < utime.size(); i++) {
        while (a + 1 < n && node_utime[a + 1] <= utime[i]) a++;
        const size_t b = std::min(a + 1, n - 1);
        double u = b > a ? double(utime[i] - node_utime[a]) / double(node_utime[b] - node_utime[a]) : 0;
        u = std::min(1.0, std::max(0.0, u));
        Eigen::Isometry3d Ci = Eigen::Isometry3d::Identity();
        Ci.linear() = Eigen::Quaterniond(C[a].linear()).slerp(u, Eigen::Quaterniond(C[b].linear())).toRotationMatrix();
        Ci.translation() = (1 - u) * C[a].translation() + u * C[b].translation();
        (*poses)[i] = Ci * (*poses)[i];
    }
}
