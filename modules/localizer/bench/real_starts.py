#!/usr/bin/env python3
"""Starts like real life on real LiDAR, the whole localizer (not only its registration):
for bench-localizer-real.

usage: real_starts.py --log SCANS.lcm --site DIR --vehicle FILE --json OUT.json
                      --report REFERENCE-REPORT.json --times TIMES.txt [--cuts 10] [--guesses 30] [--global 10] [--seconds 8] [--jobs 2]
                      [--plot PNG]

SCANS.lcm: LIDAR_SCAN + GROUND_TRUTH (base poses) from import-scans --vehicle FILE,
of scans that are not in DIR/map.pcd (bench-localizer-real: the odd keyframes, the
map from the even ones). The log is cut at --cuts points where the car moves (faster
than 3 m/s) and the next --seconds are replayed through the localizer, LiDAR alone:
  prior 3 m / 15 deg  --initial-pose drawn uniformly within 3 m (disc) and 15 degrees
                      of the reference, z off by up to 1 m (--guesses runs in all)
  no prior            nothing: global relocalization in the site map (--global runs)
Judged as bench-localizer-drive does (modules/localizer/bench/bench_starts.py): a run
converged when its first tracking POSE and every later one lie within 0.2 m of the
reference; tracking errors pool the converged runs; no prior must track within 5 s.
Cuts where the reference is implausible (REFERENCE-REPORT.json from reference.py names
the keyframes, TIMES.txt gives every keyframe's time) are counted in every row and
reported apart as well; so are cuts whose keyframes come too sparsely for any start
to be tracking within 5 s (the localizer verifies a start over verify_scans sweeps).
"""
import argparse
import json
import math
import pathlib
import re
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import bench_starts as bs  # noqa: E402
import locbench as lb  # noqa: E402


def reference_plausible(gt, flagged_s, gap_s=1.0):
    """False when the cut's span (its first to last reference pose, widened by a keyframe
    gap) holds a keyframe that reference.py flags: its poses imply a horizontal
    acceleration no car makes (over 5 m/s^2), so the reference or the keyframe times are
    wrong there, or lies before the scans first fix a step (its speed never measured).
    Judged on every keyframe, not on the cut's odd ones alone: a reversal between two odd
    keyframes (MulRan at 31.8-34.1 s) leaves the odd ones looking smooth."""
    t0, t1 = gt[0, 0] * 1e-6 - gap_s, gt[-1, 0] * 1e-6 + gap_s
    return not any(t0 <= t <= t1 for t in flagged_s)


def verify_sweeps():
    """The sweeps a start needs before it is tracking (the localizer's verify_scans),
    read from the source so the figure follows the code."""
    h = pathlib.Path(__file__).resolve().parents[1] / "core" / "localizer.h"
    m = re.search(r"\bint verify_scans = (\d+);", h.read_text())
    if not m:
        sys.exit(f"real_starts.py: {h}: no 'int verify_scans = N;'")
    return int(m.group(1))


def earliest_tracking_s(cut, sweeps):
    """When the sweeps-th sweep of the cut comes (s after its first): no start can be
    tracking before it. The keyframes here are 0.7-3.2 s apart, so on some cuts that is
    past the 5 s of the no-prior target: those cuts are the data's, not the search's."""
    t = lb.read_channel_times(cut, "LIDAR_SCAN")
    return None if len(t) < sweeps else (t[sweeps - 1] - t[0]) * 1e-6


def print_by_cut(cuts, plausible, earliest, prior_runs, global_runs):
    """Where the starts fail: per cut, the prior starts converged, the earliest a start can
    be tracking, and each no-prior start's time to track and its worst error (the failures
    sit on a few cuts)."""
    print(f"{'cut':<10} {'reference':<11} {'prior conv':>10} {'earliest':>8}  no prior (tracking s / worst m)")
    for k, c in enumerate(cuts):
        pr = prior_runs[k::len(cuts)]
        gl = global_runs[k::len(cuts)]
        g = ", ".join("never" if r["tracking_s"] is None else f"{r['tracking_s']:.1f} s / {r.get('max_m') or 0:.2f} m"
                      for r in gl)
        e = "-" if earliest[k] is None else f"{earliest[k]:.1f} s"
        print(f"{c.stem:<10} {'plausible' if plausible[k] else 'implausible':<11} "
              f"{sum(r['converged'] for r in pr):>4} of {len(pr):<3} {e:>8}  {g or '-'}")


def plot_starts(path, title, gt, cuts, plausible, earliest, sweeps, prior_runs, global_runs, flagged_s):
    """Where the starts succeed and fail, on the route: each cut's first keyframe coloured
    by its no-prior start, hollow where the reference is implausible, with the prior starts
    that converged beside it; the keyframes reference.py flags as black crosses."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    span = np.ptp(gt[:, 1:3], axis=0) + 20.0
    fig, ax = plt.subplots(figsize=(11, min(11, max(4.5, 11 * span[1] / span[0] + 1.5))))
    ax.plot(gt[:, 1], gt[:, 2], color="0.8", lw=3, zorder=1, label="reference path")
    flagged = [bs.gt_at(gt, t * 1e6) for t in flagged_s if gt[0, 0] <= t * 1e6 <= gt[-1, 0]]
    if flagged:
        ax.scatter([f[1] for f in flagged], [f[2] for f in flagged], marker="x", color="k", s=40, zorder=2,
                   label="keyframe the reference flags (over 5 m/s\u00b2, or speed not yet fixed)")
    late = f"later: its sweep {sweeps} comes after 5 s"
    kinds = {"tracking within 5 s": "tab:green", late: "tab:blue",
             "later than 5 s, or never": "tab:orange", "tracking far from the reference": "tab:red"}
    shown = set()
    for k, c in enumerate(cuts):
        g = bs.gt_at(gt, lb.read_channel_times(c, "LIDAR_SCAN")[0])
        gl, pr = global_runs[k::len(cuts)], prior_runs[k::len(cuts)]
        if any(r.get("max_m") is not None and r["max_m"] > bs.WRONG_M for r in gl):
            kind = "tracking far from the reference"
        elif all(r["converged"] and r["tracking_s"] is not None and r["tracking_s"] <= 5.0 for r in gl):
            kind = "tracking within 5 s"
        elif earliest[k] is None or earliest[k] > 5.0:
            kind = late
        else:
            kind = "later than 5 s, or never"
        col = kinds[kind]
        ax.scatter([g[1]], [g[2]], s=90, zorder=3, edgecolors=col, linewidths=2,
                   facecolors=col if plausible[k] else "none")
        shown.add(kind)
        ok = sum(r["converged"] for r in pr)
        ax.annotate(c.stem[4:] + ("" if ok == len(pr) else f" (prior {ok}/{len(pr)})"), (g[1], g[2]),
                    xytext=(0, 9 if k % 2 else -15), textcoords="offset points", fontsize=7, ha="center")
    for kind, col in kinds.items():
        if kind in shown:
            ax.scatter([], [], s=90, color=col, label=f"no prior: {kind}")
    ax.scatter([], [], s=90, edgecolors="0.3", facecolors="none", label="hollow: reference implausible there")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", required=True)
    ap.add_argument("--site", required=True)
    ap.add_argument("--vehicle", required=True)
    ap.add_argument("--json", required=True)
    ap.add_argument("--report", required=True, help="reference.py's report (implausible_keyframes_refined)")
    ap.add_argument("--times", required=True, help="every keyframe's time (s), one per line, as reference.py read them")
    ap.add_argument("--cuts", type=int, default=10)
    ap.add_argument("--guesses", type=int, default=30)
    ap.add_argument("--global", dest="n_global", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--plot", help="also draw where the starts succeed and fail on the route (PNG)")
    a = ap.parse_args()
    log, site = pathlib.Path(a.log), pathlib.Path(a.site)
    work = log.parent / "starts"
    work.mkdir(exist_ok=True)
    gt = lb.read_poses(log, "GROUND_TRUTH")
    if len(gt) < 2:
        sys.exit(f"real_starts.py: {log}: no GROUND_TRUTH")
    frames = bs.moving_cut_points(log, gt, a.cuts, a.seconds)
    cuts = []
    for at in frames:
        c = work / f"cut_{at:.1f}.lcm"
        if not c.exists():
            bs.cut(log, c, at, a.seconds, "LIDAR_SCAN,GROUND_TRUTH")
        cuts.append(c)
    # The reference is a pose graph without loop edges, over keyframes whose times are the
    # dataset's: where it implies an acceleration no car makes, the reference (or the
    # keyframe times) is wrong there, not the localizer alone.
    times = np.loadtxt(a.times, ndmin=1)
    flagged = json.loads(pathlib.Path(a.report).read_text())["implausible_keyframes_refined"]
    if any(k >= len(times) for k in flagged):
        sys.exit(f"real_starts.py: {a.report} flags keyframe {max(flagged)}, {a.times} has {len(times)}")
    plausible = [reference_plausible(lb.read_poses(c, "GROUND_TRUTH"), [times[k] for k in flagged]) for c in cuts]
    print(f"real_starts: {len(cuts)} cuts of {a.seconds:.0f} s at {', '.join(f'{t:.1f}' for t in frames)} s "
          f"(car moving), LiDAR alone, {a.jobs} at a time")
    bs.print_header()
    rng = np.random.default_rng(a.seed)
    veh = ["--vehicle", a.vehicle, "--no-gnss", "--no-imu", "--no-speed", "--site", site]
    tasks = []
    for i in range(a.guesses):
        c = cuts[i % len(cuts)]
        g = bs.gt_at(gt, lb.read_channel_times(c, "LIDAR_SCAN")[0])
        r, ang = 3.0 * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        x, y, z = g[1] + r * math.cos(ang), g[2] + r * math.sin(ang), g[3] + rng.uniform(-1, 1)
        yaw = math.degrees(g[4]) + rng.uniform(-15, 15)
        extra = veh + [f"--initial-pose={x:.3f},{y:.3f},{z:.3f},0,0,{yaw:.3f}"]
        tasks.append(lambda c=c, o=work / f"out_prior_{i}.lcm", e=extra: bs.localize_and_judge(gt, c, o, e))
    runs = prior_runs = bs.run_all(a.jobs, tasks, "prior")
    ok = [plausible[i % len(cuts)] for i in range(len(runs))]
    rows = [bs.summary("prior 3 m/15°, LiDAR-only, moving", runs),
            bs.summary("  ... where the reference is plausible", [r for r, k in zip(runs, ok) if k])]
    tasks = [lambda c=cuts[i % len(cuts)], o=work / f"out_global_{i}.lcm": bs.localize_and_judge(gt, c, o, veh)
             for i in range(a.n_global)]
    runs = bs.run_all(a.jobs, tasks, "no prior")
    ok = [plausible[i % len(cuts)] for i in range(len(runs))]
    sweeps = verify_sweeps()
    earliest = [earliest_tracking_s(c, sweeps) for c in cuts]
    reach = [earliest[i % len(cuts)] is not None and earliest[i % len(cuts)] <= 5.0 for i in range(len(runs))]
    rows += [bs.summary("no prior (global search)", runs, within_s=5.0),
             bs.summary("  ... where the reference is plausible", [r for r, k in zip(runs, ok) if k], within_s=5.0),
             bs.summary(f"  ... and sweep {sweeps} comes within 5 s",
                        [r for r, k, e in zip(runs, ok, reach) if k and e], within_s=5.0)]
    for r in rows:
        bs.print_row(r)
    print_by_cut(cuts, plausible, earliest, prior_runs, runs)
    if a.plot:
        title = (f"{log.stem} keyframes in the site of the others; labels: the cut (s into the log), and the prior "
                 f"starts converged where not all did\nno prior within 5 s: {rows[2]['converged_pct']:.1f} % of all, "
                 f"{rows[3]['converged_pct']:.1f} % where the reference is plausible, "
                 f"{rows[4]['converged_pct']:.1f} % there when sweep {sweeps} comes within 5 s")
        plot_starts(a.plot, title, gt, cuts, plausible, earliest, sweeps, prior_runs, runs, [times[k] for k in flagged])
        print(f"real_starts: picture {a.plot}")
    print(f"reference implausible (reference.py flags keyframes {flagged}: over 5 m/s^2, or before the scans "
          f"fix a step) on {plausible.count(False)} of {len(cuts)} cuts: "
          + ", ".join(f"{c.stem}" for c, k in zip(cuts, plausible) if not k))
    print("targets: >= 99% of perturbed starts within 0.2 m; tracking median <= 0.05 m, p99 <= 0.15 m, "
          "yaw p99 <= 0.5 deg; no prior: tracking within 5 s on >= 95%; no LOST")
    bs.write_json(pathlib.Path(a.json), rows)


if __name__ == "__main__":
    main()
