"""Trajectory metrics of make bench-mapper: TUM files, poses at given times, SE(3) alignment
(Umeyama, no scale), relative drift over path-length segments (the KITTI odometry measure)
and absolute trajectory error. Poses are 4x4 numpy arrays (map <- base)."""
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

DRIFT_LENGTHS_M = (100, 200, 300, 400, 500, 600, 700, 800)


def read_tum(path):
    """A TUM file ("t x y z qx qy qz qw", '#' comments): (times in s, (n, 4, 4) poses)."""
    a = np.loadtxt(path, comments="#", ndmin=2)
    if a.shape[0] == 0:
        return np.zeros(0), np.zeros((0, 4, 4))
    if a.shape[1] != 8:
        raise ValueError(f"{path}: expected 8 columns (t x y z qx qy qz qw), got {a.shape[1]}")
    return a[:, 0], to_matrices(a[:, 1:4], a[:, 4:8])


def to_matrices(xyz, quat_xyzw):
    T = np.tile(np.eye(4), (len(xyz), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:, :3, 3] = xyz
    return T


def write_tum(path, times, poses):
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    with open(path, "w") as f:
        for t, T, qq in zip(times, poses, q):
            f.write(f"{t:.6f} {T[0, 3]:.6f} {T[1, 3]:.6f} {T[2, 3]:.6f} {qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}\n")


def read_kitti(path):
    """KITTI poses (12 numbers a line, 3x4 row-major): (n, 4, 4)."""
    a = np.loadtxt(path, comments="#", ndmin=2)
    if a.shape[1] != 12:
        raise ValueError(f"{path}: expected 12 columns (3x4 row-major), got {a.shape[1]}")
    T = np.tile(np.eye(4), (len(a), 1, 1))
    T[:, :3, :] = a.reshape(-1, 3, 4)
    return T


def poses_at(times, poses, query, tol=2e-6):
    """The trajectory (times ascending) interpolated at query times (linear in position,
    slerp in rotation). Returns (mask of the queries inside [times[0], times[-1]] give or take
    tol seconds (stamps rounded to the microsecond), poses of those)."""
    keep = np.concatenate(([True], np.diff(times) > 0))  # repeated stamps: keep the first
    times, poses = times[keep], poses[keep]
    inside = (query >= times[0] - tol) & (query <= times[-1] + tol)
    q = np.clip(query[inside], times[0], times[-1])
    out = np.tile(np.eye(4), (len(q), 1, 1))
    if len(times) == 1:
        out[:] = poses[0]
        return inside, out
    for k in range(3):
        out[:, k, 3] = np.interp(q, times, poses[:, k, 3])
    out[:, :3, :3] = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
    return inside, out


def umeyama(src, dst, with_scale=False):
    """R, t, c minimising sum |c R src_i + t - dst_i|^2 (c = 1 unless with_scale; Umeyama 1991);
    src, dst: (n, 3)."""
    ms, md = src.mean(0), dst.mean(0)
    C = (dst - md).T @ (src - ms) / len(src)
    U, D, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    c = float(np.trace(np.diag(D) @ S) / np.mean(np.sum((src - ms) ** 2, axis=1))) if with_scale else 1.0
    return R, md - c * R @ ms, c


def umeyama_se3(src, dst):
    """R, t minimising sum |R src_i + t - dst_i|^2 (rigid, no scale); src, dst: (n, 3)."""
    R, t, _ = umeyama(src, dst)
    return R, t


def ate(est, gt):
    """Absolute trajectory error of positions after SE(3) alignment of est onto gt
    (same length, corresponding poses): (rmse m, max m, errors)."""
    p, g = est[:, :3, 3], gt[:, :3, 3]
    R, t = umeyama_se3(p, g)
    e = np.linalg.norm(p @ R.T + t - g, axis=1)
    return float(np.sqrt(np.mean(e ** 2))), float(np.max(e)), e


def ate_sim3(est, gt):
    """The scale of the similarity alignment of est's positions onto gt's and the largest
    position error after it: (scale, max m)."""
    p, g = est[:, :3, 3], gt[:, :3, 3]
    R, t, c = umeyama(p, g, with_scale=True)
    return c, float(np.max(np.linalg.norm(c * p @ R.T + t - g, axis=1)))


def rot_angle(R):
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0))


def relative_drift(est, gt, lengths=DRIFT_LENGTHS_M, span=None):
    """KITTI odometry drift: for every first pose i and every length L (metres of ground-truth
    path, only lengths shorter than the path), j = the first pose at least L further along;
    the error of the relative motion i -> j: translation / L and rotation / L. With span (an
    int per pose, -1 = none: possible_spans), only segments whose poses all lie in one span.
    Returns (mean translational error in %, mean rotational error in deg / 100 m, segments
    used, lengths used, per-length means as {L: (t %, r deg/100 m, n)})."""
    g = gt[:, :3, 3]
    dist = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))))
    used = [L for L in lengths if L < dist[-1]]
    inv = np.linalg.inv
    t_all, r_all, per = [], [], {}
    for L in used:
        i = np.arange(len(g))
        j = np.searchsorted(dist, dist + L, side="left")
        ok = j < len(g)
        i, j = i[ok], j[ok]
        if span is not None:
            keep = (span[i] >= 0) & (span[i] == span[j])
            i, j = i[keep], j[keep]
        if len(i) == 0:
            continue
        dg = inv(gt[i]) @ gt[j]
        de = inv(est[i]) @ est[j]
        err = inv(dg) @ de
        te = np.linalg.norm(err[:, :3, 3], axis=1) / L
        re = rot_angle(err[:, :3, :3]) / L
        t_all.append(te)
        r_all.append(re)
        per[L] = (float(np.mean(te)) * 100, float(np.degrees(np.mean(re))) * 100, int(len(i)))
    if not t_all:
        return float("nan"), float("nan"), 0, used, per
    te, re = np.concatenate(t_all), np.concatenate(r_all)
    return float(np.mean(te)) * 100, float(np.degrees(np.mean(re))) * 100, int(len(te)), used, per


def impossible_steps(times, poses, max_sideways=2.0, max_backwards=2.0, max_accel=5.0):
    """The steps k (pose k-1 to k) of a car's base trajectory that no car makes: sliding
    sideways faster than max_sideways m/s, running against its heading faster than
    max_backwards m/s (forward is the way the trajectory mostly goes in the base frame: a
    LiDAR mounted facing backwards makes it -x), or a horizontal speed changing by more than
    max_accel m/s^2 from the step before. Returns a bool per pose (True at k: step k is)."""
    n = len(poses)
    bad = np.zeros(n, dtype=bool)
    if n < 2:
        return bad
    d = poses[1:, :3, 3] - poses[:-1, :3, 3]
    dt = np.maximum(np.diff(times), 1e-6)
    body = np.einsum("kji,kj->ki", poses[:-1, :3, :3], d) / dt[:, None]    # R^T d / dt
    fwd = 1.0 if np.median(body[:, 0]) >= 0 else -1.0
    bad[1:] = (np.abs(body[:, 1]) > max_sideways) | (fwd * body[:, 0] < -max_backwards)
    speed = np.hypot(d[:, 0], d[:, 1]) / dt
    acc = np.abs(np.diff(speed)) / np.maximum(0.5 * (dt[1:] + dt[:-1]), 1e-6)
    bad[2:] |= acc > max_accel
    return bad


def possible_spans(times, poses, flagged=()):
    """Spans of a reference trajectory that a car can have driven: an int per pose, the span it
    belongs to (-1: a pose flagged or reached by an impossible step, impossible_steps). A
    span breaks at every such pose; flagged: indices of poses not to be believed anyway."""
    bad = impossible_steps(times, poses)
    bad[list(flagged)] = True
    span = np.full(len(poses), -1, dtype=int)
    cur, prev_ok = -1, False
    for k in range(len(poses)):
        if bad[k]:
            prev_ok = False
            continue
        if not prev_ok:
            cur += 1
        span[k] = cur
        prev_ok = True
    return span


def path_length(poses):
    return float(np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)))


# WGS84 (NIMA TR8350.2): the map frame of a site is the tangent plane at its origin, +x yaw
# degrees counter-clockwise from east, z up (docs/architecture.md, common/pb_geo).
WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563


def _ecef(lat_deg, lon_deg, h):
    e2 = WGS84_F * (2 - WGS84_F)
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A / np.sqrt(1 - e2 * np.sin(la) ** 2)
    return np.array([(n + h) * np.cos(la) * np.cos(lo), (n + h) * np.cos(la) * np.sin(lo), (n * (1 - e2) + h) * np.sin(la)])


def ecef_from_map(georef):
    """4x4 transform ECEF <- map of a site's georef dict (lat0_deg, lon0_deg, alt0_m, yaw_deg)."""
    la, lo = np.radians(georef["lat0_deg"]), np.radians(georef["lon0_deg"])
    enu_in_ecef = np.array([[-np.sin(lo), -np.sin(la) * np.cos(lo), np.cos(la) * np.cos(lo)],
                            [np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la) * np.sin(lo)],
                            [0.0, np.cos(la), np.sin(la)]])
    y = np.radians(georef.get("yaw_deg", 0.0))
    enu_from_map = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = enu_in_ecef @ enu_from_map
    T[:3, 3] = _ecef(georef["lat0_deg"], georef["lon0_deg"], georef["alt0_m"])
    return T


def site_from_site(dst_georef, src_georef):
    """4x4 transform between two sites' map frames: dst map <- src map (both through ECEF)."""
    return np.linalg.inv(ecef_from_map(dst_georef)) @ ecef_from_map(src_georef)
