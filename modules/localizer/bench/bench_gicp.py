#!/usr/bin/env python3
"""bench-localizer, second half: small_gicp GICP and VGICP on the scans and starts
that build/bin/bench-localizer dumped (--dump FILE, FILE.map), single thread, and
the combined table with the ratios the issue asks for.

usage: bench_gicp.py DUMP RESULTS.json [--voxel 0.5] [--rounds 5] [--reference-report R.json]
DUMP holds, per baseline scan: int32 n, float32 xyz[n] (base frame, the localizer's
own downsampling), int32 k, float64 4x4 row-major truth, tracking start, k offset starts.
PCL NDT comes from RESULTS.json (one entry per resolution); the ratios are taken
against NDT at its best resolution on this data (most converged starts, then the
smallest median error).
Ours and VGICP are also timed in turn, --rounds rounds of the same work (ours through
bench-localizer --time-dump), and the VGICP verdict takes the median of the rounds' ratios:
one pass of each, minutes apart, compares two speeds of a shared machine.
A verdict's "equal or better" means converged at least as often and, on the runs both
converged, as accurate (better_or_equal); the figures over every run are printed beside it.
With --reference-report (reference.py's report), the accuracy is also compared on the
scans where the reference is plausible: not within 3 keyframes of one whose poses imply
an acceleration no car makes (the rule of the real-data test).
"""
import argparse
import json
import os
import struct
import subprocess
import sys
import time

import numpy as np
import small_gicp

import reference  # plausible(): the real-data test's rule, beside the script that flags

TOP = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))


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
        (k,) = struct.unpack_from("<i", data, off)
        off += 4
        mats = np.frombuffer(data, dtype="<f8", count=16 * (2 + k), offset=off).reshape(2 + k, 4, 4)
        off += 8 * 16 * (2 + k)
        scans.append((pts, mats[0].copy(), mats[1].copy(), [m.copy() for m in mats[2:]]))
    return scans


def errors(T, gt):
    terr = float(np.linalg.norm(T[:3, 3] - gt[:3, 3]))
    D = gt[:3, :3].T @ T[:3, :3]
    yerr = abs(np.degrees(np.arctan2(D[1, 0], D[0, 0])))
    return terr, float(yerr)


def accuracy(te, ye, conv):
    """Accuracy figures of translation (m) and yaw (deg) errors, one per run."""
    return {"n": int(len(te)), "t_median": float(np.median(te)), "t_p99": float(np.percentile(te, 99)),
            "yaw_p99": float(np.percentile(ye, 99)), "converged": float(np.mean(te < conv))}


def summary(rows, conv):
    ms = np.array([r[0] for r in rows])
    te = np.array([r[1] for r in rows])
    ye = np.array([r[2] for r in rows])
    return {"ms_median": float(np.median(ms)), "ms_p99": float(np.percentile(ms, 99)), **accuracy(te, ye, conv),
            "errors": te.tolist(), "yaw_errors": ye.tolist()}


def accuracy_on(run, keep, conv):
    """Accuracy figures of a run's errors on the scans `keep` marks (runs in scan order,
    the same number per scan); None when the run has no per-run errors."""
    te, ye = run.get("errors"), run.get("yaw_errors")
    if not te or len(te) % len(keep):
        return None
    mask = np.repeat(np.asarray(keep), len(te) // len(keep))
    if not mask.any():
        return None
    return {**accuracy(np.asarray(te)[mask], np.asarray(ye)[mask], conv), "errors": np.asarray(te)[mask].tolist()}


def print_head(hdr):
    """A markdown table's header row and rule."""
    print(hdr)
    print("|" + "|".join("-" * (len(c)) for c in hdr.split("|")[1:-1]) + "|")


def paired(o, b, conv):
    """Accuracy of ours and a baseline on the runs both converged (the same scans and starts,
    in the same order): n, each one's median and p99 error (m; only n when it is 0); None
    when the runs do not pair up. A p99 over every run is the tail of the failures (both
    fail more than 1 % from 3 m away), which the convergence share already counts."""
    te_o, te_b = np.asarray(o.get("errors") or []), np.asarray(b.get("errors") or [])
    if not len(te_o) or len(te_o) != len(te_b):
        return None
    both = (te_o < conv) & (te_b < conv)
    if not both.any():
        return {"n": 0}
    return {"n": int(both.sum()), "ours_median": float(np.median(te_o[both])), "ours_p99": float(np.percentile(te_o[both], 99)),
            "base_median": float(np.median(te_b[both])), "base_p99": float(np.percentile(te_b[both], 99))}


def better_or_equal(o, b, conv):
    """ours at equal or better convergence and accuracy than a baseline (the rule of the speed
    verdicts): converged at least as often, and on the runs both converged a median within
    5 mm and a p99 within 2 cm of the baseline's, or better. With no run converged in both,
    only where the baseline converged on none and ours on some; False when the runs do not
    pair up."""
    p = paired(o, b, conv)
    if p is None or o["converged"] < b["converged"]:
        return False
    if p["n"] == 0:
        return b["converged"] == 0 and o["converged"] > 0
    return p["ours_median"] <= p["base_median"] + 0.005 and p["ours_p99"] <= p["base_p99"] + 0.02


def accuracy_text(o, b, conv):
    """The figures behind a better_or_equal verdict, in words."""
    p = paired(o, b, conv)
    both = ("the runs do not pair up" if p is None else "no run converged in both" if p["n"] == 0 else
            f"on the {p['n']} both converged median {p['ours_median']:.3f} vs {p['base_median']:.3f} m, "
            f"p99 {p['ours_p99']:.3f} vs {p['base_p99']:.3f} m")
    return (f"conv {100 * o['converged']:.1f} vs {100 * b['converged']:.1f}%, {both}; every run: median "
            f"{o['t_median']:.3f} vs {b['t_median']:.3f} m, p99 {o['t_p99']:.3f} vs {b['t_p99']:.3f} m")


def plausible_accuracy(report, ours, table, best, starts, label, conv):
    """The accuracy rows again on the baseline scans where the reference is plausible; the
    verdicts above stay those of every scan."""
    try:
        flagged = json.load(open(report))["implausible_keyframes_refined"]
    except (OSError, ValueError, KeyError) as e:
        sys.exit(f"bench_gicp.py: {report}: {e}")
    keep = reference.plausible(ours.get("baseline_scan_index") or [], flagged)
    print(f"\nwhere the reference is plausible ({sum(keep)} of {len(keep)} baseline scans: none within 3 keyframes "
          f"of one reference.py flags, {flagged}):")
    print_head(f"| {'method':26} | {'start':9} | {'runs':>5} | {'err med':>8} | {'err p99':>8} | {'yaw p99':>7} | "
               f"{'conv':>7} |")
    out = {"baseline_scans": len(keep), "plausible_scans": int(sum(keep)), "flagged": flagged}
    for s in starts:
        rows = [("ours, reduced input", f"ours_{s}_red", ours.get(f"ours_{s}_red"))]
        rows += [(f"PCL NDT {r:.1f} m, reduced", f"ndt{r:g}_{s}", ours.get(f"ndt{r:g}_{s}")) for r in ours.get("ndt_res", [])]
        rows += [(name, f"{m}_{s}", table[f"{m}_{s}"]) for m, name in (("gicp", "small_gicp GICP"), ("vgicp", "small_gicp VGICP"))]
        for name, key, run in rows:
            st = accuracy_on(run, keep, conv) if run and keep else None
            if st is None:
                continue
            out[key] = st
            print(f"| {name:26} | {label[s]:9} | {st['n']:5d} | {st['t_median']:8.3f} | {st['t_p99']:8.3f} | "
                  f"{st['yaw_p99']:7.3f} | {100 * st['converged']:6.1f}% |")
    for s in starts:
        o = out.get(f"ours_{s}_red")
        for key in ([f"ndt{best[0]:g}_{s}"] if best else []) + [f"gicp_{s}", f"vgicp_{s}"]:
            b = out.get(key)
            if o and b:
                print(f"  {label[s]:9} against {key.split('_')[0]:6}: "
                      f"{'equal or better' if better_or_equal(o, b, conv) else 'WORSE'} ({accuracy_text(o, b, conv)})")
    ours["where_reference_plausible"] = out


def interleaved(a, ours, scans, run, timing_runs):
    """Ours and VGICP timed in turn, a.rounds rounds of the same work each (ours through
    bench-localizer --time-dump on the dumped points and starts): a machine whose speed
    wanders over minutes slows both alike, where one pass of each minutes apart does not.
    Per round, the median ms of each and their ratio."""
    if a.rounds < 1 or not ours.get("map"):
        return None
    cmd = [a.ours, "--time-dump", a.dump, "--map", ours["map"], "--voxel", str(ours["voxel"]),
           "--timing-runs", str(timing_runs)]
    if ours.get("global"):
        cmd += ["--global", f"{ours['global_radius_m']:g},{ours['global_yaw_deg']:g}"]
    for opt in ("target_points", "coarse_iterations", "rough_targets"):
        if ours.get(opt, -1) >= 0:
            cmd += ["--" + opt.replace("_", "-"), str(ours[opt])]
    rounds = []
    for k in range(a.rounds):
        print(f"bench_gicp.py: timing round {k + 1} of {a.rounds}: ours, then small_gicp VGICP, same points and starts",
              file=sys.stderr, flush=True)
        r = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True)
        o = json.loads(r.stdout)
        v_track = [float(np.median([run("vgicp", pts, track)[0] for _ in range(timing_runs)]))
                   for pts, _, track, _ in scans]
        v_off = [run("vgicp", pts, st)[0] for pts, _, _, offs in scans for st in offs]
        if len(o["off_ms"]) != len(v_off) or len(o["track_ms"]) != len(v_track):
            sys.exit(f"bench_gicp.py: ours timed {len(o['off_ms'])} starts and {len(o['track_ms'])} scans, "
                     f"VGICP {len(v_off)} and {len(v_track)}: not the same work")
        rounds.append({s: {"ours_ms_median": float(np.median(o[f"{s}_ms"])), "vgicp_ms_median": float(np.median(v)),
                           "ratio": float(np.median(v) / np.median(o[f"{s}_ms"]))}
                       for s, v in (("track", v_track), ("off", v_off))})
    return rounds


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dump")
    ap.add_argument("results")
    ap.add_argument("--voxel", type=float, default=0.5, help="VGICP voxel and GICP target downsampling (m)")
    ap.add_argument("--rounds", type=int, default=5,
                    help="rounds of ours and VGICP timed in turn on the same work (0: none; default 5)")
    ap.add_argument("--ours", default=os.path.join(TOP, "build", "bin", "bench-localizer"),
                    help="bench-localizer binary for the rounds (default: the build's)")
    ap.add_argument("--reference-report", help="reference.py's report: also compare where the reference is plausible")
    a = ap.parse_args()
    scans = read_dump(a.dump)
    mp = np.fromfile(a.dump + ".map", dtype="<f4").reshape(-1, 3).astype(np.float64)
    ours = json.load(open(a.results))
    conv = ours.get("converge_m", 0.3)
    start_label = ours.get("start", "1m/3deg")

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

    def run(method, pts, start):
        """one small_gicp alignment, timed: source covariances (k-NN on the scan) + registration, one thread"""
        t0 = time.thread_time()
        src = small_gicp.PointCloud(pts)
        small_gicp.estimate_covariances(src, num_neighbors=20, num_threads=1)
        if method == "gicp":
            r = small_gicp.align(target, src, tree, init_T_target_source=start, registration_type="GICP",
                                 max_correspondence_distance=2.0, num_threads=1, max_iterations=30)
        else:
            r = small_gicp.align(vmap, src, init_T_target_source=start,
                                 max_correspondence_distance=2.0, num_threads=1, max_iterations=30)
        return (time.thread_time() - t0) * 1e3, np.asarray(r.T_target_source)

    res = {"gicp_track": [], "gicp_off": [], "vgicp_track": [], "vgicp_off": []}
    timing_runs = ours.get("timing_runs", 1)   # tracking aligns: median of this many runs, as bench-localizer's
    for pts, gt, track, offs in scans:
        for start_name, start in [("track", track)] + [("off", o) for o in offs]:
            for method in ("gicp", "vgicp"):
                runs = [run(method, pts, start) for _ in range(timing_runs if start_name == "track" else 1)]
                res[f"{method}_{start_name}"].append((float(np.median([t for t, _ in runs])),) + errors(runs[-1][1], gt))
    turns = interleaved(a, ours, scans, run, timing_runs)

    starts = ["track", "off"]
    label = {"track": "tracking", "off": start_label}
    ndt_res = ours.get("ndt_res", [])
    print(f"\nsmall_gicp {getattr(small_gicp, '__version__', '1.0.1')} on the same {len(scans)} baseline scans "
          f"(same reduced points and starts; map crop {len(mp)} points; target prep GICP "
          f"{t_gicp_target:.1f} s, VGICP {t_vgicp_target:.1f} s CPU; source covariances timed per scan); "
          f"conv = share of runs ending within {conv:g} m")
    hdr = f"| {'method':26} | {'start':9} | {'runs':>5} | {'ms med':>8} | {'ms p99':>8} | {'err med':>8} | " \
          f"{'err p99':>8} | {'yaw p99':>7} | {'conv':>7} |"
    print_head(hdr)
    table = {}
    for s in starts:
        rows = [("ours, raw scan in", ours[f"ours_{s}_sub"]), ("ours, reduced input", ours[f"ours_{s}_red"])]
        rows += [(f"PCL NDT {r:.1f} m, reduced", ours.get(f"ndt{r:g}_{s}")) for r in ndt_res]
        for method, name in (("gicp", "small_gicp GICP"), ("vgicp", "small_gicp VGICP")):
            table[f"{method}_{s}"] = summary(res[f"{method}_{s}"], conv)
            rows.append((name, table[f"{method}_{s}"]))
        for name, st in rows:
            if not st or st.get("n", 0) == 0:
                continue
            print(f"| {name:26} | {label[s]:9} | {st['n']:5d} | {st['ms_median']:8.2f} | {st['ms_p99']:8.2f} | "
                  f"{st['t_median']:8.3f} | {st['t_p99']:8.3f} | {st['yaw_p99']:7.3f} | {100 * st['converged']:6.1f}% |")
    # NDT at its best resolution on this data: most converged from the offset starts, then accuracy
    best = None
    for r in ndt_res:
        o = ours.get(f"ndt{r:g}_off")
        if o and o.get("n", 0) and (best is None or (o["converged"], -o["t_median"]) > best[1]):
            best = (r, (o["converged"], -o["t_median"]))
    if turns:
        print(f"\nours and small_gicp VGICP timed in turn, {len(turns)} rounds of the same points and starts "
              "(median CPU ms per run; VGICP / ours):")
        for s in starts:
            print(f"  {label[s]:9} ours " + ", ".join(f"{t[s]['ours_ms_median']:.2f}" for t in turns) +
                  "; VGICP " + ", ".join(f"{t[s]['vgicp_ms_median']:.2f}" for t in turns) +
                  "; ratio " + ", ".join(f"{t[s]['ratio']:.1f}x" for t in turns))
    print(f"\nspeed ratios (median CPU ms per run, baseline / ours, same reduced points and starts); PCL NDT at its "
          f"best resolution here: {best[0] if best else 'n/a'} m")
    ok = True
    summary_out = {}
    for s in starts:
        o = ours[f"ours_{s}_red"]
        cands = [(f"gicp_{s}", "small_gicp GICP", None), (f"vgicp_{s}", "small_gicp VGICP", 3.0)]
        if best:
            cands.insert(0, (f"ndt{best[0]:g}_{s}", f"PCL NDT {best[0]:.1f} m", 20.0))
        for key, name, need in cands:
            b = ours.get(key) if key.startswith("ndt") else table[key]
            if not b or b.get("n", 0) == 0:
                continue
            ratio = b["ms_median"] / o["ms_median"]
            how = ""
            if key.startswith("vgicp") and turns:
                # the verdict takes the rounds timed in turn; the one pass above is shown beside it
                summary_out[f"{key}_ratio_one_pass"] = ratio
                ratio = float(np.median([t[s]["ratio"] for t in turns]))
                how = f" (median of {len(turns)} rounds timed in turn; one pass: {summary_out[f'{key}_ratio_one_pass']:.1f}x)"
            acc = "equal or better" if better_or_equal(o, b, conv) else "WORSE"
            verdict = ""
            if need is not None:
                good = ratio >= need and acc != "WORSE"
                ok &= good
                verdict = f"  (target >= {need:.0f}x at equal or better convergence and accuracy: {'met' if good else 'NOT MET'})"
            summary_out[f"{key}_ratio"] = ratio
            summary_out[f"{key}_paired"] = paired(o, b, conv)
            print(f"  {label[s]:9} {name:17} {ratio:7.1f}x{how}, convergence and accuracy {acc} "
                  f"({accuracy_text(o, b, conv)}){verdict}")
    print("all speed targets met" if ok else "some speed targets NOT met (see above)")
    if a.reference_report:
        plausible_accuracy(a.reference_report, ours, table, best, starts, label, conv)
    ours.update({f"{k}": v for k, v in table.items()})
    ours["ratios"] = summary_out
    ours["vgicp_rounds_in_turn"] = turns or []
    ours["all_speed_targets_met"] = bool(ok)
    with open(a.results, "w") as f:
        json.dump(ours, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
