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

static ceres::Problem::Options problem_options()
{
    ceres::Problem::Options o;
    o.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;       /* quat is a member */
    o.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;  /* the caller's */
    return o;
}

pb_pose_graph::pb_pose_graph(const std::vector<Eigen::Isometry3d> &poses)
    : q(poses.size()), t(poses.size()), problem(problem_options())
{
    for (size_t k = 0; k < poses.size(); k++) {
        Eigen::Quaterniond qq(poses[k].linear());
        q[k] = {qq.x(), qq.y(), qq.z(), qq.w()};
        const Eigen::Vector3d &tt = poses[k].translation();
        t[k] = {tt.x(), tt.y(), tt.z()};
    }
}

void pb_pose_graph::add_edge(size_t a, size_t b, const Eigen::Isometry3d &rel, const Eigen::Matrix<double, 6, 6> &sqrt_info)
{
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<pb_relative_pose_error, 6, 4, 3, 4, 3>(
                                 new pb_relative_pose_error{rel.translation(), Eigen::Quaterniond(rel.linear()), sqrt_info}),
                             nullptr, q[a].data(), t[a].data(), q[b].data(), t[b].data());
}

int pb_pose_graph::solve(const char *what, int *iterations, pb_err_t *err)
{
    for (auto &qk : q)
        if (problem.HasParameterBlock(qk.data())) problem.SetManifold(qk.data(), &quat);
    ceres::Solver::Options sopt;
    sopt.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    sopt.num_threads = 1;
    sopt.max_num_iterations = 100;
    sopt.logging_type = ceres::SILENT;
    ceres::Solver::Summary sum;
    ceres::Solve(sopt, &problem, &sum);
    if (!sum.IsSolutionUsable())
        return pb_err_set(err, "%s: the pose graph did not solve: %s", what, sum.message.c_str()), -1;
    *iterations += (int)sum.iterations.size();
    return 0;
}

std::vector<Eigen::Isometry3d> pb_pose_graph::poses() const
{
    std::vector<Eigen::Isometry3d> out(q.size(), Eigen::Isometry3d::Identity());
    for (size_t k = 0; k < q.size(); k++) {
        out[k].linear() = Eigen::Quaterniond(q[k][3], q[k][0], q[k][1], q[k][2]).normalized().toRotationMatrix();
        out[k].translation() = Eigen::Vector3d(t[k][0], t[k][1], t[k][2]);
    }
    return out;
}
