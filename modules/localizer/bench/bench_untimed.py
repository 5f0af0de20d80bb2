#!/usr/bin/env python3
"""make bench-localizer-untimed: raw sweeps without point times, as many datasets' .bin
scans come (x y z i only), imported three ways and localized LiDAR alone.

One simulated drive (the default site, seed 4, aggressive, 60 s: up to about 14 m/s and
the loop's corners) is exported by scan-export (x y z and each point's time) and imported
by import-scans:
  point times   --bin-fields x,y,z,t: the sweep's own times (what the drivers give)
  none          --bin-fields x,y,z,_: no times, so every point is taken at the scan's time
                (right only for motion-compensated scans such as KITTI odometry's)
  azimuth       --bin-fields x,y,z,_ --spin cw: each point's time from its
                azimuth (the sweep starts at its first point: the file is in firing order)
The localizer runs on each from the true first pose (--initial-pose), LiDAR alone; errors
of the tracking POSE against GROUND_TRUTH at the POSE's time (3-D, metres; yaw, degrees).
Prints a table and writes build/bench/localizer-untimed.json."""
import argparse
import json
import math
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import locbench as lb  # noqa: E402

ROOT, BIN = lb.ROOT, lb.BIN
WORK = ROOT / "build" / "bench" / "localizer-untimed"
JSON_OUT = ROOT / "build" / "bench" / "localizer-untimed.json"
CASES = [("point times", ["--bin-fields", "x,y,z,t"]),
         ("none", ["--bin-fields", "x,y,z,_"]),
         ("azimuth", ["--bin-fields", "x,y,z,_", "--spin", "cw"])]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60, help="seconds of drive (default 60)")
    args = ap.parse_args()
    WORK.mkdir(parents=True, exist_ok=True)
    drive = WORK / "drive"
    if not lb.cached(drive / "drive.lcm"):
        print(f"simulating {args.duration:.0f} s into {drive} ...", flush=True)
        lb.sh([BIN / "simdrive", "--out", drive, "--seed", 4, "--speed-profile", "aggressive",
               "--duration", args.duration, "--quiet"])
    exp = WORK / "export"
    lb.sh([BIN / "scan-export", "--log", drive / "drive.lcm", "--out", exp, "--quiet"])
    lb.lidar_poses_tum(exp, WORK / "lidar.tum")
    gt0 = np.loadtxt(exp / "ground_truth.tum", max_rows=1)
    qx, qy, qz, qw = gt0[4:8]
    yaw = math.degrees(math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)))
    init = f"--initial-pose={gt0[1]},{gt0[2]},{gt0[3]},0,0,{yaw}"
    speeds = np.hypot(*np.diff(np.loadtxt(exp / "ground_truth.tum")[:, 1:3], axis=0).T) / 0.01
    rows = []
    for i, (name, extra) in enumerate(CASES):
        print(f"[{i + 1}/{len(CASES)}] {name}: import-scans, localizer ...", flush=True)
        log, out = WORK / f"case{i}.lcm", WORK / f"case{i}.out.lcm"
        lb.sh([BIN / "import-scans", "--scans", exp / "scans", "--poses", WORK / "lidar.tum", "--times",
               exp / "times.txt", "--vehicle", ROOT / "vehicles" / "prius2017.yaml", "--out", log, "--quiet", *extra])
        p = lb.run_localizer(log, out, [init, "--no-imu", "--no-speed", "--no-gnss"])
        if p.returncode != 0:
            raise SystemExit(f"localizer on {log} exited {p.returncode}: {p.stderr}")
        poses = lb.read_poses(out, "POSE")
        status = np.bincount(poses[:, 5].astype(int), minlength=4)
        _, et, ey = lb.errors_vs_truth(poses[poses[:, 5] == 1], lb.read_poses(log, "GROUND_TRUTH"))
        rows.append({"case": name, "import_args": extra, "poses": int(len(poses)),
                     "tracking": int(status[1]), "degraded": int(status[2]), "lost": int(status[3]),
                     "median_m": float(np.median(et)), "p99_m": float(np.percentile(et, 99)),
                     "max_m": float(np.max(et)), "yaw_p99_deg": float(np.percentile(ey, 99))})
        log.unlink()
    print(f"\nLiDAR alone from the true start, {len(poses)} sweeps, speed up to {speeds.max():.1f} m/s")
    print(f"{'times':<12} {'tracking':>8} {'degraded':>8} {'LOST':>5} {'median m':>9} {'p99 m':>7} {'max m':>7} "
          f"{'yaw p99':>8}")
    for r in rows:
        print(f"{r['case']:<12} {r['tracking']:>8} {r['degraded']:>8} {r['lost']:>5} {r['median_m']:>9.3f} "
              f"{r['p99_m']:>7.3f} {r['max_m']:>7.3f} {r['yaw_p99_deg']:>8.3f}")
    JSON_OUT.write_text(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
                                    "drive": "simdrive --seed 4 --speed-profile aggressive --duration "
                                             f"{args.duration:g}", "max_speed_mps": float(speeds.max()),
                                    "rows": rows}, indent=1))
    print(f"wrote {JSON_OUT}")


if __name__ == "__main__":
    main()
