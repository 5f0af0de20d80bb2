/* registration: robust point-to-plane Gauss-Newton against the voxel-hashed
 * map (see registration.h). */
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"   /* Eigen 3.4 6x6 eigen solver false positive */
#include "registration.h"
#include "regmap_impl.h"
#include "window_search.h"

#include <algorithm>
#include <cmath>
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

using namespace pb_loc;

void pb_reg_config_default(pb_reg_config_t *cfg)
{
    *cfg = pb_reg_config_t();
}

Eigen::Isometry3d pb_reg_from_transform(const pb_transform_t *t)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::Quaterniond(t->q[0], t->q[1], t->q[2], t->q[3]).normalized().toRotationMatrix();
    T.translation() = Eigen::Vector3d(t->t[0], t->t[1], t->t[2]);
    return T;
}

void pb_reg_to_transform(const Eigen::Isometry3d &T, pb_transform_t *out)
{
    Eigen::Quaterniond q(T.rotation());
    q.normalize();
    if (q.w() < 0) q.coeffs() *= -1;   /* one sign, for byte-identical output */
    out->q[0] = q.w(); out->q[1] = q.x(); out->q[2] = q.y(); out->q[3] = q.z();
    for (int a = 0; a < 3; a++) out->t[a] = T.translation()(a);
}

namespace {

/* A voxel's sum and count side by side (one cache line a point, not two). */
struct VoxelSum {
    float s[3];
    int n;
};

/* One voxel-grid pass: centroid per voxel, in first-seen order (deterministic), into out;
 * returns the number of voxels. hash and acc are scratch. */
size_t voxel_centroids(const float *xyz, size_t n, double voxel, VoxelHash *hash, std::vector<VoxelSum> *acc,
                       std::vector<float> *out)
{
    double inv = 1.0 / voxel;
    hash->reset(std::min<size_t>(n / 2 + 16, 1 << 15));
    acc->clear();
    uint64_t last_key = VoxelHash::kEmpty;   /* neighbouring points often share a voxel: no lookup then */
    VoxelSum *v = nullptr;
    KeyBatch batch;
    for (size_t i = 0; batch.next(xyz, n, &i, inv, *hash) > 0;) {
        for (int j = 0; j < batch.n; j++) {
            const float *p = xyz + 3 * batch.point[j];
            if (batch.key[j] != last_key) {
                bool inserted;
                const int32_t k = hash->insert(batch.key[j], (int32_t)acc->size(), &inserted);
                if (inserted) acc->push_back(VoxelSum{{0.f, 0.f, 0.f}, 0});
                v = &(*acc)[(size_t)k];
                last_key = batch.key[j];
            }
            v->s[0] += p[0]; v->s[1] += p[1]; v->s[2] += p[2];
            v->n++;
        }
    }
    out->resize(3 * acc->size());
    for (size_t j = 0; j < acc->size(); j++)
        for (int a = 0; a < 3; a++) (*out)[3 * j + a] = (*acc)[j].s[a] / (float)(*acc)[j].n;
    return acc->size();
}

struct Params {
    int max_iterations;
    double max_corr, min_corr, kernel, eps_m, eps_rad, inlier;
    bool rough_targets;
    double line_along_view;
    Eigen::Vector3d view;   /* the LiDAR's origin in base: where a point was seen from */
};

struct Accum {
    Eigen::Matrix<double, 6, 6> H;
    Eigen::Matrix<double, 6, 1> g;
    double cost, wsum, ss;   /* ss: squared residuals of the matched points */
    int matched, inliers;
};

/* The points' residual variance: their mean square residual over the degrees of freedom left
 * (the scale of the result's covariance and of a prior beside the points). */
inline double residual_variance(double ss, int matched)
{
    return std::max(ss / std::max(matched - 6, 1), 1e-6);
}

/* The guess as a prior (pb_reg_align_prior): the pose it is about and its information. */
struct Prior {
    Eigen::Isometry3d at;
    Eigen::Matrix<double, 6, 6> info;
};

/* Points whose nearest target (of any kind, at any distance) is upright, and
 * how many of them are inliers: the divergence evidence of fill_result. */
struct Upright {
    int points, inliers;
};

/* The targets near each point at its last voxel: Gauss-Newton moves points by
 * millimetres between steps, so most keep their voxel and skip the hash look-ups
 * (the align's main cost: every look-up misses the cache on a large map). */
struct NearCache {
    const Level *lv = nullptr;
    std::vector<uint64_t> key;        /* voxel key of each point at its last look-up */
    std::vector<uint8_t> n;
    std::vector<const Cell *> near;   /* 7 per point */
    std::vector<const Rough *> rough; /* the point's rough target when no cell is near, else NULL */

    /* for npts points on level (emptied when either changes) */
    void prepare(const Level &level, size_t npts)
    {
        if (lv == &level && key.size() == npts) return;
        lv = &level;
        key.assign(npts, ~(uint64_t)0);
        n.assign(npts, 0);
        near.assign(7 * npts, nullptr);
        rough.assign(npts, nullptr);
    }

    /* the targets near point i, now at q; *r (when r is given, as it is for every call of
     * one align or none): its rough target when there are none */
    int lookup(size_t i, const Eigen::Vector3d &q, const Cell *const **out, const Rough **r)
    {
        uint64_t k;
        *out = &near[7 * i];
        if (r) *r = nullptr;
        if (!voxel_key_of(q(0), q(1), q(2), lv->inv_voxel, &k)) return 0;
        if (key[i] != k) {
            key[i] = k;
            n[i] = (uint8_t)lv->lookup_near(q(0), q(1), q(2), &near[7 * i]);
            rough[i] = n[i] || !r ? nullptr : rough_at(*lv, k);
        }
        if (r) *r = rough[i];
        return n[i];
    }

    /* the rough target of voxel k, or NULL */
    static const Rough *rough_at(const Level &lv, uint64_t k)
    {
        if (lv.roughs.empty()) return nullptr;
        int32_t j = lv.rough.find(k);
        return j >= 0 && lv.roughs[(size_t)j].target() ? &lv.roughs[(size_t)j] : nullptr;
    }
};

/* A rough target's residual gate, in standard deviations: a point farther from the
 * Gaussian is not of it. */
const double kRoughGate = 3.0;

bool cell_upright(const Cell *c)
{
    return c->kind == CELL_LINE ? std::fabs(c->u1[2]) + std::fabs(c->u2[2]) > 0.7 : std::fabs(c->u1[2]) < 0.7;
}

/* h += w j j^T, as its lower triangle by rows (element b, a holds H(a, b), a <= b):
 * written out, since Eigen's 6x6 rankUpdate is an out-of-line call per point (a fifth of
 * a start-up align's time); the products in Eigen's order, so the sums are the same to
 * the bit, and each row's run contiguous, so it vectorises */
inline void rank_update(double h[6][6], const Eigen::Matrix<double, 6, 1> &j, double w)
{
    for (int b = 0; b < 6; b++) {
        double wb = w * j(b);
        for (int a = 0; a <= b; a++) h[b][a] += wb * j(a);
    }
}

/* A point among foliage, against its cell's Gaussian (NDT's target, here only where no plane
 * or line is near): three residuals kernel * C^-1/2 (q - mean), so one standard deviation
 * off weighs as one kernel off a plane, with the same Geman-McClure weight on the whole
 * distance. They steer the steps but are no inliers: the inlier share and the checks built
 * on it still count planes and lines only. */
inline void add_rough(const Rough &r, const Eigen::Vector3d &q, const Eigen::Vector3d &s, double kernel,
                      double h[6][6], Accum *acc)
{
    const Eigen::Vector3d d(q(0) - r.mean[0], q(1) - r.mean[1], q(2) - r.mean[2]);
    const Eigen::Vector3d rows[3] = {{r.w[0], r.w[1], r.w[2]}, {r.w[1], r.w[3], r.w[4]}, {r.w[2], r.w[4], r.w[5]}};
    double m[3], m2 = 0;
    for (int a = 0; a < 3; a++) { m[a] = rows[a].dot(d); m2 += m[a] * m[a]; }
    if (m2 > kRoughGate * kRoughGate) return;
    double w = 1.0 / (1.0 + m2);   /* k^2 / (k^2 + e^2) with e = kernel m */
    w *= w;
    for (int a = 0; a < 3; a++) {
        const Eigen::Vector3d u = kernel * rows[a];
        Eigen::Matrix<double, 6, 1> j;
        j.head<3>() = u;
        j.tail<3>() = s.cross(u);
        rank_update(h, j, w);
        acc->g.noalias() += (w * kernel * m[a]) * j;
    }
}

/* Linearises every point at pose T: J^T W J and J^T W r over the points whose
 * cell residual is within gate, with Geman-McClure weights of scale kernel.
 * cache: the points' targets from an earlier pass over the same points (NULL: none). */
void linearise(const Level &lv, const float *pts, size_t n, const Eigen::Isometry3d &T, double gate,
               double kernel, const Params &pa, Accum *acc,
               std::vector<float> *abs_residuals, Upright *up = nullptr, NearCache *cache = nullptr)
{
    const double inlier = pa.inlier;
    const bool rough_targets = pa.rough_targets;
    if (cache) cache->prepare(lv, n);
    if (up) up->points = up->inliers = 0;
    acc->g.setZero();
    acc->cost = acc->wsum = acc->ss = 0;
    acc->matched = acc->inliers = 0;
    const Eigen::Matrix3d R = T.linear();
    const Eigen::Vector3d t = T.translation();
    const Eigen::Vector3d view = R * pa.view;
    const double k2 = kernel * kernel, gate2 = gate * gate;
    double h[6][6] = {};
    for (size_t i = 0; i < n; i++) {
        Eigen::Vector3d p(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]);
        Eigen::Vector3d s = R * p;          /* point about the vehicle, map axes */
        Eigen::Vector3d q = s + t;
        /* the own cell's target, else the nearest of the face neighbours' */
        const Cell *buf[7];
        const Cell *const *near = buf;
        const Rough *rough = nullptr;
        int nn;
        if (cache) {
            nn = cache->lookup(i, q, &near, rough_targets ? &rough : nullptr);
        } else {
            nn = lv.lookup_near(q(0), q(1), q(2), buf);
            uint64_t k;
            if (nn == 0 && rough_targets && voxel_key_of(q(0), q(1), q(2), lv.inv_voxel, &k))
                rough = NearCache::rough_at(lv, k);
        }
        const Cell *c = nullptr;
        double r1 = 0, r2 = 0, best = HUGE_VAL;
        Eigen::Vector3d u1, u2;
        for (int k = 0; k < nn; k++) {
            const Cell *ck = near[k];
            Eigen::Vector3d d(q(0) - ck->mean[0], q(1) - ck->mean[1], q(2) - ck->mean[2]);
            Eigen::Vector3d a(ck->u1[0], ck->u1[1], ck->u1[2]), b(ck->u2[0], ck->u2[1], ck->u2[2]);
            double ra = a.dot(d), rb = ck->kind == CELL_LINE ? b.dot(d) : 0.0;
            if (ra * ra + rb * rb < best) { best = ra * ra + rb * rb; c = ck; r1 = ra; r2 = rb; u1 = a; u2 = b; }
        }
        if (up && c && cell_upright(c)) {
            up->points++;
            if (best < inlier * inlier) up->inliers++;
        }
        if (!c) {
            if (rough && rough_targets) add_rough(*rough, q, s, kernel, h, acc);
            continue;
        }
        double e2 = r1 * r1 + r2 * r2;
        if (e2 > gate2) continue;
        const bool two = c->kind == CELL_LINE;   /* a line: two residuals, across it */
        if (two && pa.line_along_view != 1.0) {
            /* A pole's or trunk's returns lie on the arc that faces the sensor, and the
             * line target passes through the centroid of the arcs the map saw: along the
             * view the offset is partly the arcs', not the pose's (a map seen from behind
             * shortens a path: a Sim(3) scale of 1.0006 on a street of poles). Across the
             * view it is unbiased: the line's residuals turn to across and along the view,
             * the one along weighs less, and the one across alone judges the point (its
             * robust weight, inlier or not): an arc's offset is no outlier. */
            const Eigen::Vector3d axis = u1.cross(u2), across = axis.cross(s - view);
            const double len = across.norm();
            if (len > 1e-9) {
                const Eigen::Vector3d d(q(0) - c->mean[0], q(1) - c->mean[1], q(2) - c->mean[2]);
                u1 = across / len;
                u2 = pa.line_along_view * axis.cross(u1);
                r1 = u1.dot(d);
                r2 = u2.dot(d);
                e2 = r1 * r1;
            }
        }
        acc->matched++;
        acc->ss += e2;
        if (e2 < inlier * inlier) acc->inliers++;
        if (abs_residuals) abs_residuals->push_back((float)std::sqrt(e2));
        double w = k2 / (k2 + e2);
        acc->cost += 1.0 - w;               /* Geman-McClure rho / k^2 */
        acc->wsum += w;
        w *= w;                             /* IRLS weight of Geman-McClure */
        /* d r / d(dt, dθ) for t += dt, R = Exp(dθ) R:  [u, s x u] */
        Eigen::Matrix<double, 6, 1> j;
        j.head<3>() = u1;
        j.tail<3>() = s.cross(u1);
        rank_update(h, j, w);
        acc->g.noalias() += (w * r1) * j;
        if (two) {
            j.head<3>() = u2;
            j.tail<3>() = s.cross(u2);
            rank_update(h, j, w);
            acc->g.noalias() += (w * r2) * j;
        }
    }
    for (int a = 0; a < 6; a++)
        for (int b = 0; b < 6; b++) acc->H(a, b) = a <= b ? h[b][a] : h[a][b];
}

Eigen::Matrix3d exp_so3(const Eigen::Vector3d &w)
{
    double a = w.norm();
    if (a < 1e-12) return Eigen::Matrix3d::Identity();
    return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

/* Whether poses a and b are more than m or rad apart (by default 1 degree: distinct
 * minima, or a run that moved far). */
bool apart(const Eigen::Isometry3d &a, const Eigen::Isometry3d &b, double m, double rad = M_PI / 180)
{
    Eigen::Isometry3d D = a.inverse() * b;
    return D.translation().norm() > m || Eigen::AngleAxisd(D.linear()).angle() > rad;
}

/* A minimum already known, and how near a run must come to be taken as ending in it. */
struct Basin {
    Eigen::Isometry3d at;
    double m, rad;
};

/* Gauss-Newton on one level from T (updated in place). Returns iterations and
 * whether the step became small. Stops early (*aborted) when abort_far_m > 0 and its
 * first steps go far (see align_points), or when it comes within basin->m and ->rad of
 * basin->at (taken as where it would end). */
int gauss_newton(const Level &lv, const float *pts, size_t n, const Params &pa, Eigen::Isometry3d *T,
                 bool *converged, double abort_far_m = 0, bool *aborted = nullptr, NearCache *cache = nullptr,
                 const Basin *basin = nullptr, const Prior *prior = nullptr)
{
    NearCache local;
    if (!cache) cache = &local;
    const Eigen::Isometry3d T_start = *T;
    if (aborted) *aborted = false;
    double gate = pa.max_corr;
    *converged = false;
    int it = 0;
    Accum acc;
    while (it < pa.max_iterations) {
        it++;
        /* the kernel widens with the gate so that far-off starts still pull */
        double kernel = std::max(pa.kernel, gate / 3.0);
        linearise(lv, pts, n, *T, gate, kernel, pa, &acc, nullptr, nullptr, cache);
        if (acc.matched < 30) break;
        Eigen::Matrix<double, 6, 6> H = acc.H;
        Eigen::Matrix<double, 6, 1> g = acc.g;
        if (prior) {
            /* the points weigh 1 / sigma^2 (their mean square residual), the prior its
             * information: both on the points' scale */
            double sigma2 = residual_variance(acc.ss, acc.matched);
            Eigen::Matrix<double, 6, 1> e;
            e.head<3>() = T->translation() - prior->at.translation();
            Eigen::AngleAxisd d(T->linear() * prior->at.linear().transpose());
            e.tail<3>() = d.angle() * d.axis();
            H += sigma2 * prior->info;
            g += sigma2 * (prior->info * e);
        }
        /* light damping keeps unobservable directions (e.g. along a straight
         * corridor) at the guess instead of drifting */
        double lam = 1e-6 * H.trace() / 6.0 + 1e-9;
        H.diagonal().array() += lam;
        Eigen::Matrix<double, 6, 1> dx = H.ldlt().solve(-g);
        if (!dx.allFinite()) break;
        T->translation() += dx.head<3>();
        T->linear() = exp_so3(dx.tail<3>()) * T->linear();
        double step_t = dx.head<3>().norm(), step_r = dx.tail<3>().norm();
        bool small = step_t < pa.eps_m && step_r < pa.eps_rad;
        /* a guess this poor is better served by the coarse level */
        if (abort_far_m > 0 && it <= 3 &&
            ((T->translation() - T_start.translation()).norm() > abort_far_m ||
             Eigen::AngleAxisd(T_start.linear().transpose() * T->linear()).angle() > M_PI / 180 ||
             (it == 3 && (step_t > 0.05 * abort_far_m || step_r > 0.05 * M_PI / 180)))) {
            if (aborted) *aborted = true;
            break;
        }
        if (small && gate <= pa.min_corr) { *converged = true; break; }
        /* within the basin's reach of a known minimum: taken as ending there */
        if (basin && !apart(basin->at, *T, basin->m, basin->rad)) {
            if (aborted) *aborted = true;
            break;
        }
        /* the gate follows the step: shrink towards min_corr as we settle */
        gate = std::max(pa.min_corr, std::min(gate, 0.5 * gate + 5.0 * step_t + 10.0 * step_r));
    }
    /* re-orthonormalise the rotation after the updates */
    Eigen::Quaterniond q(T->linear());
    T->linear() = q.normalized().toRotationMatrix();
    return it;
}

void fill_result(const Level &lv, const float *pts, size_t n, const Eigen::Isometry3d &T, const Params &pa,
                 pb_reg_result_t *res, NearCache *cache)
{
    std::vector<float> absr;
    absr.reserve(n);
    Accum acc;
    Upright up;
    linearise(lv, pts, n, T, pa.min_corr, pa.kernel, pa, &acc, &absr, &up, cache);
    res->points_used = (int)n;
    res->points_matched = acc.matched;
    res->overlap = n ? (double)acc.matched / (double)n : 0;
    res->inlier_fraction = n ? (double)acc.inliers / (double)n : 0;
    res->score = n ? acc.wsum / (double)n : 0;
    double ss = 0;
    for (float a : absr) ss += (double)a * a;
    res->rmse_m = absr.empty() ? 0 : std::sqrt(ss / absr.size());
    if (!absr.empty()) {
        std::nth_element(absr.begin(), absr.begin() + absr.size() / 2, absr.end());
        res->median_abs_m = absr[absr.size() / 2];
    } else {
        res->median_abs_m = 0;
    }
    res->upright_points = up.points;
    res->upright_inlier_fraction = up.points ? (double)up.inliers / up.points : NAN;
    /* covariance: sigma^2 H^-1, sigma^2 from the robust residuals */
    Eigen::Matrix<double, 6, 6> H = acc.H;
    if (acc.matched > 6) {
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(H / acc.matched);
        res->hessian_eigenvalues = es.eigenvalues();
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> et(H.topLeftCorner<3, 3>());
        double lo = std::max(et.eigenvalues()(0), 1e-12);
        res->condition = et.eigenvalues()(2) / lo;
        double sigma2 = residual_variance(ss, acc.matched);
        H.diagonal().array() += 1e-6 * H.trace() / 6.0 + 1e-9;
        res->covariance = sigma2 * H.inverse();
    } else {
        res->hessian_eigenvalues.setZero();
        res->condition = HUGE_VAL;
        res->covariance = Eigen::Matrix<double, 6, 6>::Identity() * 1e6;
    }
}

Params params_of(const pb_reg_config_t *cfg)
{
    Params pa;
    pa.max_iterations = cfg->max_iterations;
    pa.max_corr = cfg->max_corr_m;
    pa.min_corr = std::min(cfg->min_corr_m, cfg->max_corr_m);
    pa.kernel = cfg->kernel_m;
    pa.eps_m = cfg->step_eps_m;
    pa.eps_rad = cfg->step_eps_rad;
    pa.inlier = cfg->inlier_m;
    pa.rough_targets = cfg->rough_targets != 0;
    pa.line_along_view = cfg->line_along_view;
    pa.view = Eigen::Vector3d(cfg->view_xyz[0], cfg->view_xyz[1], cfg->view_xyz[2]);
    return pa;
}

/* Coarse-level parameters: gate and kernel in proportion to the coarse cell,
 * stopping at centimetre steps (the fine level finishes). */
Params coarse_params(const Params &fine, double coarse_voxel, int iterations)
{
    Params pc = fine;
    pc.max_iterations = iterations;
    pc.max_corr = 2.0 * coarse_voxel;
    pc.min_corr = coarse_voxel;
    pc.kernel = 0.25 * coarse_voxel;
    pc.inlier = 0.25 * coarse_voxel;
    pc.eps_m = 0.01;
    pc.eps_rad = 0.1 * M_PI / 180.0;
    return pc;
}

/* Every align starts here: the result says "bad input" at the guess until the inputs pass. */
bool start_result(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &guess,
                  pb_reg_result_t *res, pb_err_t *err)
{
    res->status = PB_REG_BAD_INPUT;
    res->pose = guess;
    res->covariance = Eigen::Matrix<double, 6, 6>::Identity() * 1e6;
    res->hessian_eigenvalues.setZero();
    res->condition = HUGE_VAL;
    res->iterations = res->points_used = res->points_matched = 0;
    res->overlap = res->inlier_fraction = res->rmse_m = res->median_abs_m = res->score = 0;
    res->upright_inlier_fraction = NAN;
    res->upright_points = 0;
    if (!map || !xyz) return pb_err_set(err, "registration: no map or no points"), false;
    if (n == 0) return pb_err_set(err, "registration: empty scan"), false;
    if (!guess.matrix().allFinite()) return pb_err_set(err, "registration: non-finite initial guess"), false;
    return true;
}

}  // namespace

void pb_reg_downsample(const float *xyz, size_t n, const pb_reg_config_t *cfg, std::vector<float> *out)
{
    /* range filter: drop the car's own body and far, sparse returns */
    std::vector<float> kept(3 * n);
    size_t nk = 0;
    const float r2min = (float)(cfg->min_range_m * cfg->min_range_m), r2max = (float)(cfg->max_range_m * cfg->max_range_m);
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + 3 * i;
        float r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
        const double *b = cfg->body_box;
        if (p[0] >= b[0] && p[1] >= b[1] && p[2] >= b[2] && p[0] <= b[3] && p[1] <= b[4] && p[2] <= b[5]) continue;
        if (r2 >= r2min && r2 <= r2max) {   /* false for NaN */
            kept[3 * nk] = p[0]; kept[3 * nk + 1] = p[1]; kept[3 * nk + 2] = p[2];
            nk++;
        }
    }
    kept.resize(3 * nk);
    VoxelHash hash;
    std::vector<VoxelSum> acc;
    double voxel = cfg->scan_voxel_m;
    size_t voxels = voxel_centroids(kept.data(), kept.size() / 3, voxel, &hash, &acc, out);
    /* adaptive: coarsen the already reduced cloud until near the target count */
    size_t target = cfg->target_points > 0 ? (size_t)cfg->target_points : 0;
    std::vector<float> tmp;
    while (target && voxels > target + target / 4 && voxel < 8.0) {
        voxel *= std::sqrt((double)voxels / (double)target) > 1.3 ? 1.3 : 1.1;
        tmp.swap(*out);
        voxels = voxel_centroids(tmp.data(), tmp.size() / 3, voxel, &hash, &acc, out);
    }
}

namespace {

/* Whether minimum T2 explains more of the scan than T (d1: how far the run to T had
 * gone from the guess when it stopped or ended). With a prior (prior_sigma_m > 0), a
 * stop beyond 3 sigma of the guess must explain clearly more (3 sigma of a count) than
 * the one nearer. On sparse or corridor-like real scans minima metres apart often
 * differ by a handful of inliers, and taking the larger count slid tracking away; in
 * porous crowns two stops 0.29 m apart (one basin by min_corr) differed by 2 of 1,915,
 * and the farther one took a track 0.28 m off. Otherwise (no prior, or both stops
 * near the guess) more inliers wins. */
bool second_wins(const Level &lv, const float *pts, size_t m, const Params &pa, double prior_sigma_m,
                 const Eigen::Isometry3d &guess, const Eigen::Isometry3d &T, double d1, const Eigen::Isometry3d &T2,
                 NearCache *cache, NearCache *cache2)
{
    Accum a1, a2;
    linearise(lv, pts, m, T, pa.min_corr, pa.kernel, pa, &a1, nullptr, nullptr, cache);
    linearise(lv, pts, m, T2, pa.min_corr, pa.kernel, pa, &a2, nullptr, nullptr, cache2);
    double d2 = (guess.inverse() * T2).translation().norm();
    bool far_unlikely = prior_sigma_m > 0 && std::max(d1, d2) > 3 * prior_sigma_m;
    double margin = far_unlikely ? 3.0 * std::sqrt((double)(d2 < d1 ? a2 : a1).inliers) : 0.0;
    /* the farther result pays the margin */
    return a2.inliers - (d2 < d1 ? 0.0 : margin) > a1.inliers - (d2 < d1 ? margin : 0.0);
}

/* Steps 2-4 of pb_reg_align on points already reduced by step 1 (res started). With
 * `known` (a minimum already found) and no coarse retry, a fine run that comes into it
 * stops there and sets *same (res then holds no result). */
int align_points(const pb_regmap_t *map, const std::vector<float> &pts, const Eigen::Isometry3d &guess,
                 const pb_reg_config_t *cfg, pb_reg_result_t *res, const Basin *known = nullptr,
                 bool *same = nullptr, const Prior *pr = nullptr)
{
    size_t m = pts.size() / 3;
    Params pa = params_of(cfg);
    /* 2. fine level from the guess: robust point-to-plane Gauss-Newton, gate
     *    shrinking; enough when tracking */
    Eigen::Isometry3d T = guess;
    bool converged = false, aborted = false;
    bool can_coarse = cfg->coarse_iterations > 0 && !map->coarse.cells.empty();
    NearCache cache;
    res->iterations = gauss_newton(map->fine, pts.data(), m, pa, &T, &converged, can_coarse ? pa.min_corr : 0,
                                   &aborted, &cache, can_coarse ? nullptr : known, pr);
    if (same && (*same = !can_coarse && known && aborted)) return res->status;
    /* 3. if that did not settle, or had to move far (a poor guess), retry
     *    coarse-to-fine: a few steps on the coarse level (every 4th point, planes
     *    over ~3 coarse cells, wide gate) pull in starts a metre or degrees off;
     *    keep whichever result has more inliers (the fine run stops early when
     *    it moves more than min_corr or 1 deg in its first 3 steps, or is still
     *    taking large steps at the 3rd) */
    bool moved_far = apart(guess, T, pa.min_corr);
    double d1 = (guess.inverse() * T).translation().norm();   /* how far the fine run went */
    if (can_coarse && (aborted || !converged || moved_far)) {
        std::vector<float> sub;
        sub.reserve(pts.size() / 4 + 3);
        for (size_t i = 0; i < m; i += 4) sub.insert(sub.end(), &pts[3 * i], &pts[3 * i] + 3);
        Params pc = coarse_params(pa, map->coarse.voxel, cfg->coarse_iterations);
        Eigen::Isometry3d T2 = guess;
        bool conv2 = false;
        res->iterations += gauss_newton(map->coarse, sub.data(), sub.size() / 3, pc, &T2, &conv2);
        NearCache cache2;
        res->iterations += gauss_newton(map->fine, pts.data(), m, pa, &T2, &conv2, 0, nullptr, &cache2, nullptr, pr);
        /* an aborted run stopped on its way: finish it, so that two minima are compared,
         * not a minimum and a pose still centimetres short of its own. Without a prior
         * the guess has no claim on its own minimum: the run is followed on every 4th
         * point first, and where it comes within min_corr / 1 deg of the coarse-to-fine
         * result it is taken to end in that minimum, which stands (from a metre off a
         * whole finish is up to 12 steps on all points, mostly to the same minimum) */
        bool prior = cfg->prior_sigma_m > 0, in_basin = false, settled;
        const Basin b2 = { T2, pa.min_corr, M_PI / 180 };
        if (aborted && !prior)
            res->iterations += gauss_newton(map->fine, sub.data(), sub.size() / 3, pa, &T, &settled, 0, &in_basin,
                                            nullptr, &b2, pr);
        if (aborted && !in_basin)
            res->iterations += gauss_newton(map->fine, pts.data(), m, pa, &T, &converged, 0, &in_basin, &cache,
                                            prior ? nullptr : &b2, pr);
        bool use_t2 = in_basin || second_wins(map->fine, pts.data(), m, pa, cfg->prior_sigma_m, guess, T,
                                              d1, T2, &cache, &cache2);
        if (use_t2) {
            T = T2;
            converged = conv2;
            std::swap(cache, cache2);
        }
    }
    /* 4. scores, covariance and divergence evidence at the result */
    int its = res->iterations;
    fill_result(map->fine, pts.data(), m, T, pa, res, &cache);
    res->iterations = its;
    /* the pose, or the guess if too few points matched */
    if (res->points_matched < 30) {
        res->status = PB_REG_FEW_POINTS;
        res->pose = guess;
    } else {
        res->status = converged ? PB_REG_OK : PB_REG_MAX_ITER;
        res->pose = T;
    }
    return res->status;
}

}  // namespace

/* pb_reg_align and pb_reg_align_prior (prior_cov NULL: none). */
static int align_scan(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &guess,
                      const Eigen::Matrix<double, 6, 6> *prior_cov, const pb_reg_config_t *cfg, pb_reg_result_t *res,
                      pb_err_t *err)
{
    pb_reg_config_t def;
    if (!cfg) cfg = (pb_reg_config_default(&def), &def);
    if (!start_result(map, xyz, n, guess, res, err)) return res->status;
    Prior pr;
    if (prior_cov) {
        Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(*prior_cov);
        pr = { guess, llt.solve(Eigen::Matrix<double, 6, 6>::Identity()) };
        if (llt.info() != Eigen::Success || !pr.info.allFinite())
            return pb_err_set(err, "registration: the prior's covariance is not positive definite"), res->status;
    }
    /* 1. downsample the scan (range filter + adaptive voxel grid) */
    std::vector<float> pts;
    pb_reg_downsample(xyz, n, cfg, &pts);
    return align_points(map, pts, guess, cfg, res, nullptr, nullptr, prior_cov ? &pr : nullptr);
}

int pb_reg_align(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &guess,
                 const pb_reg_config_t *cfg, pb_reg_result_t *res, pb_err_t *err)
{
    return align_scan(map, xyz, n, guess, nullptr, cfg, res, err);
}

int pb_reg_align_prior(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &guess,
                       const Eigen::Matrix<double, 6, 6> &prior_cov, const pb_reg_config_t *cfg, pb_reg_result_t *res,
                       pb_err_t *err)
{
    return align_scan(map, xyz, n, guess, &prior_cov, cfg, res, err);
}

int pb_reg_align_global(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &seed,
                        double radius_m, double yaw_range_rad, const pb_reg_config_t *cfg, pb_reg_result_t *res,
                        pb_err_t *err)
{
    pb_reg_config_t def;
    if (!cfg) cfg = (pb_reg_config_default(&def), &def);
    if (!start_result(map, xyz, n, seed, res, err)) return res->status;
    /* 1. the sweep reduced once, for the search and the refinements */
    std::vector<float> pts;
    pb_reg_downsample(xyz, n, cfg, &pts);
    if (pts.empty()) return res->status = PB_REG_FEW_POINTS;
    /* 2. every position and yaw of the window scored on the map's structure; the best
     *    few distinct ones kept */
    window_config_t wc;
    wc.radius_m = std::max(radius_m, 0.0);
    wc.yaw_range_rad = std::min(std::max(yaw_range_rad, 0.0), M_PI);
    std::vector<window_candidate_t> cand;
    int scored = 0;
    window_search(columns_of(map), pts.data(), pts.size() / 3, seed, wc, &cand, &scored);
    /* no structure in the window (an open square): the seed is all there is */
    if (cand.empty()) cand.push_back({ seed, 0 });
    /* 3. the candidates are refined on 2/5 of the points (every 2.5th), without the
     *    coarse retry (each is within a cell and a yaw step of its minimum) and to steps
     *    of a millimetre or two (enough to rank them): near-equals (a road alike both
     *    ways) are told apart by their inliers; a candidate whose run comes within
     *    2 cm / 0.1 deg of the best minimum so far is that minimum again and is dropped
     *    there (on the HDL-32E pair most windows give two candidates, and the second
     *    ended in the first's minimum; within 0.3 m / 1 deg cost LiDAR-alone starts on
     *    the porous street of trees, where minima that near differ). The best is then
     *    refined on all the points from the wide gate, as any guess is: the gate's
     *    narrowing settles closer to the truth than a start at the narrow gate, and a
     *    wide window (a sparse moving start searches 20 m around its seeds) can leave
     *    the best cell metres from the minimum (the coarse retry). A refinement that
     *    ran out of steps (a weakly held direction, as along a street) goes on from its
     *    result. */
    std::vector<float> sub;
    for (size_t i = 0; 5 * i / 2 < pts.size() / 3; i++) {
        const float *q = &pts[3 * (5 * i / 2)];
        sub.insert(sub.end(), q, q + 3);
    }
    pb_reg_config_t quick = *cfg;
    quick.coarse_iterations = 0;
    quick.step_eps_m = 3 * cfg->step_eps_m;
    quick.step_eps_rad = 3 * cfg->step_eps_rad;
    int total_it = 0;
    double most = -1;
    Eigen::Isometry3d from = cand[0].pose;
    for (const window_candidate_t &c : cand) {
        pb_reg_result_t r;
        if (!start_result(map, sub.data(), sub.size() / 3, c.pose, &r, err)) break;
        bool same = false;
        const Basin best = { from, cfg->same_minimum_m, cfg->same_minimum_rad };
        bool stop = most >= 0 && cfg->same_minimum_m > 0;
        align_points(map, sub, c.pose, &quick, &r, stop ? &best : nullptr, &same);
        total_it += r.iterations;
        if (same) continue;
        if (r.status != PB_REG_FEW_POINTS && r.inlier_fraction > most) {
            most = r.inlier_fraction;
            from = r.pose;
        }
    }
    align_points(map, pts, from, cfg, res);
    total_it += res->iterations;
    if (res->status == PB_REG_MAX_ITER) {
        Eigen::Isometry3d again = res->pose;
        align_points(map, pts, again, cfg, res);
        total_it += res->iterations;
    }
    res->iterations = total_it;
    return res->status;
}

double pb_reg_structure_fit(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &pose,
                            double inlier_m, double rough_m)
{
    if (!map || n == 0) return NAN;
    const Level &lv = map->fine;
    const Eigen::Matrix3d R = pose.linear();
    const Eigen::Vector3d t = pose.translation();
    size_t fit = 0;
    for (size_t i = 0; i < n; i++) {
        Eigen::Vector3d q = R * Eigen::Vector3d(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]) + t;
        const Cell *near[7];
        int nn = lv.lookup_near(q(0), q(1), q(2), near);
        bool ok = false;
        for (int k = 0; k < nn && !ok; k++) {
            Eigen::Vector3d d(q(0) - near[k]->mean[0], q(1) - near[k]->mean[1], q(2) - near[k]->mean[2]);
            double ra = d.dot(Eigen::Vector3d(near[k]->u1[0], near[k]->u1[1], near[k]->u1[2]));
            double rb = near[k]->kind == CELL_LINE ? d.dot(Eigen::Vector3d(near[k]->u2[0], near[k]->u2[1], near[k]->u2[2])) : 0;
            ok = ra * ra + rb * rb < inlier_m * inlier_m;
        }
        if (!ok && lv.rough.size() > 0) {
            /* rough structure: the point's own cell, or a cell within rough_m of it */
            int64_t ix, iy, iz;
            uint64_t key;
            if (voxel_index_of(q(0), q(1), q(2), lv.inv_voxel, &ix, &iy, &iz) && voxel_key(ix, iy, iz, &key))
                ok = lv.rough.find(key) >= 0;
            for (int a = 0; a < 3 && !ok; a++)
                for (int sgn = -1; sgn <= 1 && !ok; sgn += 2) {
                    Eigen::Vector3d o = q;
                    o(a) += sgn * rough_m;
                    ok = voxel_key_of(o(0), o(1), o(2), lv.inv_voxel, &key) && lv.rough.find(key) >= 0;
                }
        }
        fit += ok;
    }
    return (double)fit / (double)n;
}
