#!/usr/bin/env python3
"""Reference poses for bench-localizer-real: a pose-graph refinement of a LiDAR
sequence's SLAM poses, built with small_gicp (GICP), not with the localizer's own
registration, so the benchmark does not judge our registration against itself.

usage: reference.py --scans DIR --poses POSES.txt --out REFINED.txt [--report R.json]

Steps, each printed as it runs:
 1. every scan is downsampled (0.5 m voxels) and its covariances estimated once;
 2. pairs: each scan with the next --pair-span scans; scan j is aligned to scan i
    with GICP, started from the input's relative pose and from starts 2 m
    ahead and behind along it (a SLAM estimate can be metres off between neighbours);
    the start with the most inliers wins; a pair whose inlier share (points within
    --corr of the other scan) is below --min-fit gives no edge;
 3. all poses are solved at once by robust least squares over the edges (Cauchy
    loss on the translation / rotation residual in units of 5 cm / 0.2 deg, scale
    15 cm), the
    input's frame kept (the best rigid motion onto the input is removed);
 4. with --rounds > 1, rounds repeat from the solved poses (one GICP start per pair, the pair dropped if
    it lands more than 0.5 m from the solution) until no pose moves 1 cm.
Quality, printed and in the report: pair residuals at the solution, the share of
pairs kept, and the spread of independent registrations (each consecutive pair
aligned from 4 starts 1 m off the solution: the largest distance between results).
Writes one KITTI line (3x4 row-major) per scan, for import-scans --poses.
"""
import argparse
import json
import os
import sys
import time

import numpy as np
import small_gicp
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "modules", "webui"))
import sitedata  # noqa: E402  (read_pcd)


def read_pcd(path):
    """x y z of a PCD scan (the web UI's reader: ascii or binary, errors name the file)."""
    try:
        x, y, z = sitedata.read_pcd(path)
    except sitedata.SiteError as e:
        sys.exit(f"reference.py: {e}")
    a = np.column_stack([x, y, z]).astype(np.float64)
    return a[np.isfinite(a).all(axis=1)]


def read_kitti(path):
    poses = []
    for ln, line in enumerate(open(path), 1):
        v = line.split()
        if not v or v[0].startswith("#"):
            continue
        if len(v) != 12:
            sys.exit(f"reference.py: {path}:{ln}: {len(v)} numbers, a KITTI pose line has 12")
        poses.append(np.vstack([np.array(v, float).reshape(3, 4), [0, 0, 0, 1]]))
    return poses


def to_vec(T):
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def to_mat(v):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(v[3:]).as_matrix()
    T[:3, 3] = v[:3]
    return T


SIG_T, SIG_R = 0.05, np.radians(0.2)


def solve(poses, edges):
    """Robust least squares over the edges (i, j, Z = T_i^-1 T_j); pose 0 held."""
    n = len(poses)
    x0 = np.concatenate([to_vec(T) for T in poses[1:]])
    T0 = poses[0]

    def pose(x, k):
        return T0 if k == 0 else to_mat(x[6 * (k - 1):6 * k])

    def resid(x):
        r = np.empty(6 * len(edges))
        for e, (i, j, Z) in enumerate(edges):
            D = np.linalg.inv(Z) @ np.linalg.inv(pose(x, i)) @ pose(x, j)
            r[6 * e:6 * e + 3] = D[:3, 3] / SIG_T
            r[6 * e + 3:6 * e + 6] = Rotation.from_matrix(D[:3, :3]).as_rotvec() / SIG_R
        return r

    sp = lil_matrix((6 * len(edges), 6 * (n - 1)), dtype=int)
    for e, (i, j, _) in enumerate(edges):
        for k in (i, j):
            if k > 0:
                sp[6 * e:6 * e + 6, 6 * (k - 1):6 * k] = 1
    # Cauchy at 15 cm. Measured on MulRan: every pair then looks like an outlier and the
    # poses stay the input's; a graduated scale (2 m, then 15 cm) moved a pose 16 m instead
    x = least_squares(resid, x0, jac_sparsity=sp, loss="cauchy", f_scale=3.0, x_scale="jac", max_nfev=50).x
    out = [T0] + [to_mat(x[6 * k:6 * k + 6]) for k in range(n - 1)]
    return out


def back_to_input_frame(poses, ref):
    """The rigid motion that best maps the solved positions onto the input's (Kabsch)."""
    a = np.array([T[:3, 3] for T in poses])
    b = np.array([T[:3, 3] for T in ref])
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1, 1, d]) @ U.T
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = cb - R @ ca
    return [A @ T for T in poses]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", required=True, help="folder of .pcd scans (file-name order; scan k goes with pose k)")
    ap.add_argument("--poses", required=True, help="KITTI poses (map <- LiDAR), one line per scan")
    ap.add_argument("--out", required=True)
    ap.add_argument("--report")
    ap.add_argument("--pair-span", type=int, default=3, help="each scan is paired with the next N (default 3)")
    ap.add_argument("--voxel", type=float, default=0.5)
    ap.add_argument("--corr", type=float, default=1.0, help="GICP correspondence distance, m (default 1)")
    ap.add_argument("--min-fit", type=float, default=0.5, help="inlier share a pair needs (default 0.5)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="rounds (default 1: on MulRan a 2nd round re-registering from the solution kept "
                         "218 of 492 pairs and moved a pose 0.9 m, so more rounds do not converge there)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    files = sorted(f for f in os.listdir(args.scans) if f.endswith(".pcd"))
    ref = read_kitti(args.poses)
    n = min(len(files), len(ref))
    if len(files) != len(ref):
        print(f"reference.py: {len(files)} scans and {len(ref)} poses: the first {n} are used", file=sys.stderr)
    t0 = time.time()
    clouds = []
    for k in range(n):
        pts = read_pcd(os.path.join(args.scans, files[k]))
        r = np.linalg.norm(pts[:, :2], axis=1)
        clouds.append(small_gicp.preprocess_points(pts[(r > 2.0) & (r < 80)], args.voxel, num_threads=args.threads))
    print(f"reference.py: {n} scans read and prepared in {time.time() - t0:.1f} s", flush=True)

    def align(i, j, guess):
        tgt, tree = clouds[i]
        src = clouds[j][0]
        r = small_gicp.align(tgt, src, tree, init_T_target_source=guess, registration_type="GICP",
                             max_correspondence_distance=args.corr, num_threads=args.threads, max_iterations=30)
        return r.T_target_source, r.num_inliers / max(1, src.size()), r.converged

    pairs = [(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + args.pair_span))]
    poses = list(ref)
    history, edges = [], []
    for rnd in range(args.rounds):
        t1 = time.time()
        edges, fits = [], []
        for p, (i, j) in enumerate(pairs):
            if p and p % 100 == 0:
                print(f"reference.py: round {rnd + 1}: {p}/{len(pairs)} pairs ({time.time() - t1:.0f} s)", flush=True)
            rel = np.linalg.inv(poses[i]) @ poses[j]
            starts = [rel]
            if rnd == 0:
                fwd = rel[:3, 3] / max(np.linalg.norm(rel[:3, 3]), 1e-6)
                for s in (-2.0, 2.0):
                    g = rel.copy()
                    g[:3, 3] += s * fwd
                    starts.append(g)
            best = max((align(i, j, g) for g in starts), key=lambda t: t[1])
            T, fit, _ = best
            if fit < args.min_fit:
                continue
            if rnd > 0 and np.linalg.norm((np.linalg.inv(rel) @ T)[:3, 3]) > 0.5:
                continue
            edges.append((i, j, T))
            fits.append(fit)
        deg = np.zeros(n, int)
        for i, j, _ in edges:
            deg[i] += 1
            deg[j] += 1
        new = back_to_input_frame(solve(poses, edges), ref)
        moved = max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(new, poses))
        poses = new
        history.append({"round": rnd + 1, "edges": len(edges), "pairs": len(pairs), "no_edge": int((deg == 0).sum()),
                        "largest_move_m": float(moved), "s": round(time.time() - t1, 1)})
        print(f"reference.py: round {rnd + 1}: {len(edges)}/{len(pairs)} pairs kept (inlier share median "
              f"{np.median(fits):.2f}), {int((deg == 0).sum())} scans without one, largest move {moved:.3f} m "
              f"({time.time() - t1:.0f} s)", flush=True)
        if moved < 0.01:
            break
    # quality: residuals of the kept pairs at the solution; spread of independent registrations
    res_t, res_r = [], []
    for i, j, Z in edges:
        D = np.linalg.inv(Z) @ np.linalg.inv(poses[i]) @ poses[j]
        res_t.append(float(np.linalg.norm(D[:3, 3])))
        res_r.append(float(np.degrees(np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec()))))
    spread = []
    for i in range(n - 1):
        rel = np.linalg.inv(poses[i]) @ poses[i + 1]
        ends = []
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            g = rel.copy()
            g[:3, 3] += rel[:3, :3] @ np.array([dx, dy, 0.0])
            T, fit, _ = align(i, i + 1, g)
            ends.append(T[:3, 3])
        ends = np.array(ends)
        spread.append(float(np.max(np.linalg.norm(ends[:, None] - ends[None], axis=2))))
    change = [float(np.linalg.norm(a[:3, 3] - b[:3, 3])) for a, b in zip(poses, ref)]
    q = lambda v, p: float(np.percentile(v, p)) if len(v) else float("nan")
    rep = {"scans": n, "rounds": history, "pairs_kept": len(edges), "pairs": len(pairs),
           "pair_resid_m_median": q(res_t, 50), "pair_resid_m_p90": q(res_t, 90), "pair_resid_deg_p90": q(res_r, 90),
           "spread_m_median": q(spread, 50), "spread_m_p90": q(spread, 90),
           "change_m_median": q(change, 50), "change_m_p90": q(change, 90), "change_m_max": max(change),
           "spread_m": spread, "pair_resid_m": res_t}
    print(f"  pair residuals at the solution ({len(edges)} pairs): median {rep['pair_resid_m_median']:.3f} m "
          f"p90 {rep['pair_resid_m_p90']:.3f} m, rotation p90 {rep['pair_resid_deg_p90']:.3f} deg")
    print(f"  spread of consecutive-pair registrations from 4 starts 1 m off: median {rep['spread_m_median']:.3f} m "
          f"p90 {rep['spread_m_p90']:.3f} m")
    print(f"  refined minus input position: median {rep['change_m_median']:.2f} m p90 {rep['change_m_p90']:.2f} m "
          f"max {rep['change_m_max']:.2f} m")
    with open(args.out, "w") as f:
        for T in poses:
            f.write(" ".join(f"{v:.9g}" for v in T[:3, :].ravel()) + "\n")
    if args.report:
        with open(args.report, "w") as f:
            json.dump(rep, f, indent=1)


if __name__ == "__main__":
    main()
