#!/usr/bin/env python3
"""bench-localizer, second half: small_gicp GICP and VGICP on the scans and starts
that build/bin/bench-localizer dumped (--dump FILE, FILE.map), single thread, and
the combined table with the ratios the issue asks for.

usage: bench.py DUMP RESULTS.json [--voxel 0.5]
DUMP holds, per baseline scan: int32 n, float32 xyz[n] (base frame, the localizer's
own downsampling), float64 4x4 row-major truth, tracking start, offset start.
"""
import argparse
import json
import struct
import sys
import time

import numpy as np
import small_gicp


def read_dump(path):
    scans = []
    with open(path, "rb") as f:
        data = f.read()
    off = 0
    while off < len(data):
        (n,) = struct.unpack_from("<i", data, off)
        off += 4
        pts = np.frombuffer(data, dtype="<f4", count=3 * n, offset=off).reshape(n, 3).astype(np.float64)
        off += 12 * n
        mats = np.frombuffer(data, dtype="<f8", count=48, offset=off).reshape(3, 4, 4)
        off += 8 * 48
        scans.append((pts, mats[0].copy(), mats[1].copy(), mats[2].copy()))
    return scans


def errors(T, gt):
    terr = float(np.linalg.norm(T[:3, 3] - gt[:3, 3]))
    D = gt[:3, :3].T @ T[:3, :3]
    yerr = abs(np.degrees(np.arctan2(D[1, 0], D[0, 0])))
    return terr, float(yerr)


def summary(rows):
    ms = np.array([r[0] for r in rows])
    te = np.array([r[1] for r in rows])
    ye = np.array([r[2] for r in rows])
    return {"n": len(rows), "ms_median": float(np.median(ms)), "ms_p99": float(np.percentile(ms, 99)),
            "t_median": float(np.median(te)), "t_p99": float(np.percentile(te, 99)),
            "yaw_p99": float(np.percentile(ye, 99)), "within_0.3": float(np.mean(te < 0.3))}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dump")
    ap.add_argument("results")
    ap.add_argument("--voxel", type=float, default=0.5, help="VGICP voxel and GICP target downsampling (m)")
    a = ap.parse_args()
    scans = read_dump(a.dump)
    mp = np.fromfile(a.dump + ".map", dtype="<f4").reshape(-1, 3).astype(np.float64)
    ours = json.load(open(a.results))
    global_mode = ours.get("global", False)

    # Targets prepared once (not timed per scan), single thread like ours.
    t0 = time.process_time()
    target = small_gicp.PointCloud(mp)
    small_gicp.estimate_covariances(target, num_neighbors=20, num_threads=1)
    tree = small_gicp.KdTree(target, num_threads=1)
    t_gicp_target = time.process_time() - t0
    t0 = time.process_time()
    vmap = small_gicp.GaussianVoxelMap(a.voxel)
    vmap.insert(target)
    t_vgicp_target = time.process_time() - t0

    res = {"gicp_track": [], "gicp_off": [], "vgicp_track": [], "vgicp_off": []}
    for pts, gt, track, off in scans:
        for start_name, start in (("track", track), ("off", off)):
            if global_mode and start_name == "track":
                continue
            for method in ("gicp", "vgicp"):
                # per scan: source covariances (k-NN on the scan) + registration, one thread
                t0 = time.thread_time()
                src = small_gicp.PointCloud(pts)
                small_gicp.estimate_covariances(src, num_neighbors=20, num_threads=1)
                if method == "gicp":
                    r = small_gicp.align(target, src, tree, init_T_target_source=start, registration_type="GICP",
                                         max_correspondence_distance=2.0, num_threads=1, max_iterations=30)
                else:
                    r = small_gicp.align(vmap, src, init_T_target_source=start,
                                         max_correspondence_distance=2.0, num_threads=1, max_iterations=30)
                ms = (time.thread_time() - t0) * 1e3
                res[f"{method}_{start_name}"].append((ms,) + errors(np.asarray(r.T_target_source), gt))

    starts = ["off"] if global_mode else ["track", "off"]
    label = {"track": "tracking", "off": "global" if global_mode else "1m/3deg"}
    print(f"\nsmall_gicp {getattr(small_gicp, '__version__', '1.0.1')} on the same {len(scans)} baseline scans "
          f"(same reduced points and starts; map crop {len(mp)} points; target prep GICP "
          f"{t_gicp_target:.1f} s, VGICP {t_vgicp_target:.1f} s CPU; source covariances timed per scan)")
    hdr = f"| {'method':22} | {'start':9} | {'scans':>5} | {'ms med':>8} | {'ms p99':>8} | {'err med':>8} | " \
          f"{'err p99':>8} | {'yaw p99':>7} | {'< 0.3 m':>7} |"
    print(hdr)
    print("|" + "|".join("-" * (len(c)) for c in hdr.split("|")[1:-1]) + "|")
    table = {}
    for s in starts:
        rows = [("ours, raw scan in", ours[f"ours_{s}_sub"]), ("ours, reduced input", ours[f"ours_{s}_red"]),
                ("PCL NDT, reduced input", ours[f"ndt_{s}"])]
        for method, name in (("gicp", "small_gicp GICP"), ("vgicp", "small_gicp VGICP")):
            table[f"{method}_{s}"] = summary(res[f"{method}_{s}"])
            rows.append((name, table[f"{method}_{s}"]))
        for name, st in rows:
            if not st or st.get("n", 0) == 0:
                continue
            print(f"| {name:22} | {label[s]:9} | {st['n']:5d} | {st['ms_median']:8.2f} | {st['ms_p99']:8.2f} | "
                  f"{st['t_median']:8.3f} | {st['t_p99']:8.3f} | {st['yaw_p99']:7.3f} | {100 * st['within_0.3']:6.1f}% |")
    print("\nspeed ratios (median CPU ms per scan, baseline / ours, same reduced points and starts):")
    ok = True
    for s in starts:
        o = ours[f"ours_{s}_red"]
        for key, name, need in ((f"ndt_{s}", "PCL NDT", 20.0), (f"vgicp_{s}", "small_gicp VGICP", 3.0),
                                (f"gicp_{s}", "small_gicp GICP", None)):
            b = ours.get(key) if key.startswith("ndt") else table[key]
            if not b or b.get("n", 0) == 0:
                continue
            ratio = b["ms_median"] / o["ms_median"]
            acc = "equal or better" if o["t_median"] <= b["t_median"] + 0.005 and o["t_p99"] <= b["t_p99"] + 0.02 \
                else "WORSE"
            verdict = ""
            if need is not None:
                good = ratio >= need and acc != "WORSE"
                ok &= good
                verdict = f"  (target >= {need:.0f}x at equal or better accuracy: {'met' if good else 'NOT MET'})"
            print(f"  {label[s]:9} {name:17} {ratio:7.1f}x, accuracy {acc} "
                  f"(median {o['t_median']:.3f} vs {b['t_median']:.3f} m, p99 {o['t_p99']:.3f} vs {b['t_p99']:.3f} m)"
                  f"{verdict}")
    print("all speed targets met" if ok else "some speed targets NOT met (see above)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
