#!/usr/bin/env python3
"""make bench-mapper: the mapper's trajectory against KISS-ICP odometry on the same scans.

Drives:
  hills   maps/hills, 30 s aggressive (grades, crests, sags): bench-terrain-localizer's cached
          drive, else simulated the same way into build/bench/mapper/hills/.
  sim     the default site's full loop (seed 4, aggressive, 232 s, about 1.5 km): the drive
          cached by bench-localizer-drive (build/bench-localizer-drive/s4_aggressive_232/
          drive.lcm) when it is there, else simulated the same way into build/bench/mapper/sim/.
  trees   the same loop (the same options) on a street of trees: the default site without its
          buildings, canopies porous to the LiDAR (simdrive --foliage-depth 0.7: a beam into a
          canopy stops at a random depth inside it, mean 0.7 m, or goes through, anew every sweep,
          as real foliage does), into build/bench/mapper/trees/. What real roadsides are made of,
          and the simulator's hard case: the crowns' returns move with the car's view.
  mulran  MulRan Riverside02 keyframes from ../shared/data (only if that folder exists; never
          copied): imported with import-scans --vehicle vehicles/lidar_mast.yaml. Reference =
          the dataset's poses (FAST-LIO2 + SC-PGO, an estimate, not ground truth); also against
          build/bench/localizer-real/refined_poses.txt when bench-localizer-real made it.

Per drive: build/bin/scan-export writes the sweeps as points (decoded by common/pb_scan); KISS-ICP
(PyPI kiss-icp, Python API, its default config with data.max_range = the sensor's range,
deskew on with the per-point times, registration.max_num_threads = 1 and OMP/TBB limited to one
thread) registers every sweep, timed per frame in CPU time; ours runs as `build/bin/mapper
--log DRIVE.lcm --out OUTDIR --vehicle FILE` and is read from
OUTDIR/trajectory.tum (after loop closure), OUTDIR/odometry.tum (before, if written) and
OUTDIR/report.json. Both are scored against the reference (base poses in map):
  drift %, deg/100m   KITTI relative drift: mean over every start pose and every segment of
                      100, 200, ..., 800 m of reference path (lengths shorter than the path) of
                      translation error / length and rotation error / length
  ATE rmse, max       position error after a rigid SE(3) (Umeyama, no scale) alignment
  scale, ATE max sim3 the scale of a similarity (Sim(3)) alignment and the position error after
                      it: what of the ATE is a trajectory too long or too short, which a loop
                      closure cannot see (a scaled loop still closes)
  ms med, p99         CPU ms per frame (KISS-ICP: one core; ours: its main thread, from its
                      report, without adding the sweep to the local map, done on another thread)
  ms mean             CPU ms per frame, mean (ours: every thread of the process over the odometry
                      pass, those that add to the local map and build the registration maps
                      too): the figure compared
  RTF                 real-time factor: scan period (median spacing of the drive's sweeps) /
                      mean CPU time per frame
  drift where possible (MulRan's references, both estimates): the same drift over the segments
                      whose reference poses a car can have driven (trajmetrics.possible_spans:
                      no step sliding sideways or running against the heading faster than
                      2 m/s, no speed changing faster than 5 m/s^2, none the refined
                      reference's report flags); also per start
On a drive of 600 sweeps or fewer (hills, MulRan) KISS-ICP runs --runs times too, each run just
before one of ours (so that both meet the shared host in the same state), and the CPU time per
frame compared is each method's median run (the other drives are too long to repeat
KISS-ICP; ours runs once on MulRan's drive with IMU and CAN, if any).
On the LiDAR alone ours runs --runs times (default 3) on each simulated drive: the whole mapper's
real-time factor is the drive's length over the median wall time of those runs (the host is
shared and noisy), and the runs' files are compared byte for byte (a run that differs is a
defect: the bench says so and exits 1 after writing its JSON).
The simulated drives' maps are also scored against the simulated world (simdrive --surface-distance
with the drive's own options, so it knows the drive's road users): the share of points within 5 cm of
a true static surface, the share farther than 0.5 m (sorted into on moving objects, on the car's own
body, other), and the points on moving objects (count and share; the target is none).
Prints a table and writes build/bench/mapper.json.
"""
import os

# one thread for KISS-ICP and numpy (KISS-ICP's TBB is also limited by registration.max_num_threads = 1),
# set before they load
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "TBB_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import datetime  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402
import platform  # noqa: E402
import shlex  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import lcm  # noqa: E402
import numpy as np  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(HERE))
import trajmetrics as tm  # noqa: E402

BIN = ROOT / "build" / "bin"
OUT = ROOT / "build" / "bench" / "mapper"
JSON_OUT = ROOT / "build" / "bench" / "mapper.json"
MULRAN = (ROOT / ".." / "shared" / "data" / "lidar_seq_mulran_riverside02_part1").resolve()
REFINED = ROOT / "build" / "bench" / "localizer-real" / "refined_poses.txt"
SIM_CACHED = ROOT / "build" / "bench-localizer-drive" / "s4_aggressive_232" / "drive.lcm"
SIM_ARGS = ["--seed", "4", "--speed-profile", "aggressive", "--duration", "232", "--quiet"]  # as bench_drive.py
# a drive this short (sweeps) is run --runs times by both KISS-ICP and ours, and the median
# run's time compared: one run of each, minutes apart on a shared host, differed by up to 20 %
SHORT_DRIVE_SWEEPS = 600
SIM_SENSOR_RANGE_M = 120.0    # vehicles/prius2017.yaml simulation.lidar_max_range
OS1_64_RANGE_M = 120.0        # Ouster OS1-64 (MulRan) datasheet range


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def sh(args, **kw):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} exited {p.returncode}\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    return p


def newer(path, *inputs):
    path = pathlib.Path(path)
    return path.exists() and all(path.stat().st_mtime >= pathlib.Path(i).stat().st_mtime
                                 for i in inputs if pathlib.Path(i).exists())


# ---------------------------------------------------------------- drives

def simulated(name, args, inputs):
    """build/bench/mapper/NAME/drive.lcm from simdrive ARGS, simulated again when older than inputs."""
    d = OUT / name
    log_path = d / "drive.lcm"
    if not newer(log_path, BIN / "simdrive", *inputs):
        log(f"simulating {name} into {d} (simdrive {' '.join(args)}) ...")
        tmp = d.with_name(name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        sh([BIN / "simdrive", "--out", tmp, *args])
        d.mkdir(parents=True, exist_ok=True)
        (tmp / "drive.lcm").replace(log_path)
        shutil.rmtree(tmp, ignore_errors=True)
    return log_path


def sim_drive(sim_log):
    if sim_log:
        return pathlib.Path(sim_log), f"given log {sim_log}"
    if SIM_CACHED.exists():
        return SIM_CACHED, f"cached by bench-localizer-drive ({SIM_CACHED.relative_to(ROOT)})"
    inputs = [ROOT / "maps" / "default" / f for f in ("site.yaml", "route.yaml", "world.yaml")]
    return simulated("sim", SIM_ARGS, inputs), f"simdrive {' '.join(SIM_ARGS)}"


TREES_FOLIAGE_M = "0.7"   # as bench-localizer-trees' porous street


def trees_drive():
    """The loop of SIM_ARGS on bench-localizer-trees' street (the default site without its
    buildings; files only: the mapper makes the map), canopies porous to the LiDAR, simulated
    again when older than the default site's files. Returns (log, site, simdrive options)."""
    sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
    import tree_street
    site = OUT / "trees" / "site"
    if not newer(site / "world.yaml", *(ROOT / "maps" / "default" / f for f in ("site.yaml", "route.yaml", "world.yaml"))):
        tree_street.street_site_files(site)
    args = ["--foliage-depth", TREES_FOLIAGE_M, *SIM_ARGS]
    return simulated("trees", ["--site", str(site), *args], [site / "world.yaml"]), site, args


HILLS_CACHED = ROOT / "build" / "bench-terrain-loc" / "loc-hills-aggressive-1" / "drive.lcm"
HILLS_ARGS = ["--site", str(ROOT / "maps" / "hills"), "--seed", "1", "--speed-profile", "aggressive", "--duration", "30",
              "--quiet"]   # as bench-terrain-localizer's


def hills_drive():
    """maps/hills, 30 s aggressive (grades, crests and sags): bench-terrain-localizer's drive
    when it is cached, else simulated the same way."""
    if HILLS_CACHED.exists():
        return HILLS_CACHED
    return simulated("hills", HILLS_ARGS, [ROOT / "maps" / "hills" / f for f in ("site.yaml", "route.yaml", "world.yaml")])


def mulran_drive():
    d = OUT / "mulran"
    d.mkdir(parents=True, exist_ok=True)
    log_path = d / "drive.lcm"
    src = [MULRAN / "optimized_poses.txt", MULRAN / "times.txt", BIN / "import-scans"]
    if not newer(log_path, *src):
        log("importing MulRan Riverside02 keyframes (import-scans --vehicle vehicles/lidar_mast.yaml) ...")
        sh([BIN / "import-scans", "--scans", MULRAN / "Scans", "--poses", MULRAN / "optimized_poses.txt",
            "--times", MULRAN / "times.txt", "--vehicle", ROOT / "vehicles" / "lidar_mast.yaml",
            "--out", log_path, "--quiet"])
    return log_path


def mulran_refined_reference(base_from_lidar, path):
    """The refined reference of bench-localizer-real (KITTI LiDAR poses, one per keyframe, at
    the dataset's times) as base poses in map, if that run made it, with the times of the
    keyframes its report does not believe (for the drift where it is possible)."""
    if not path.exists():
        return []
    times = np.atleast_1d(np.loadtxt(MULRAN / "times.txt"))
    P = tm.read_kitti(path)
    n = min(len(P), len(times))
    rep = path.parent / "reference-report.json"
    flagged = json.loads(rep.read_text())["implausible_keyframes_refined"] if rep.exists() else []
    return [("refined (bench-loc-real)", times[:n], P[:n] @ np.linalg.inv(base_from_lidar),
             times[[k for k in flagged if k < n]])]


# ---------------------------------------------------------------- KISS-ICP

def export(log_path, out_dir, vehicle):
    out_dir = pathlib.Path(out_dir)
    stamp = out_dir / "times.txt"
    if newer(stamp, log_path, BIN / "scan-export") and (out_dir / "base_from_lidar.txt").exists():
        return out_dir
    shutil.rmtree(out_dir, ignore_errors=True)
    args = [BIN / "scan-export", "--log", log_path, "--out", out_dir, "--quiet"]
    if vehicle:
        args += ["--vehicle", vehicle]
    sh(args)
    return out_dir


def read_export(d):
    d = pathlib.Path(d)
    times = np.atleast_1d(np.loadtxt(d / "times.txt"))
    files = sorted((d / "scans").glob("*.bin"))
    if len(files) != len(times):
        raise RuntimeError(f"{d}: {len(files)} scan files but {len(times)} lines in times.txt")
    B = np.loadtxt(d / "base_from_lidar.txt", comments="#")
    return times, files, B


def kiss_config(max_range):
    """KISS-ICP's default config with data.max_range = the sensor's range and one thread; the
    voxel size then follows KISS-ICP's own rule (max_range / 100, as its load_config does)."""
    from kiss_icp.config.parser import KISSConfig
    for k in os.environ:
        if k.lower().startswith("kiss_icp_"):
            raise RuntimeError(f"environment variable {k} would change KISS-ICP's config; unset it")
    cfg = KISSConfig()
    cfg.data.max_range = max_range
    cfg.data.deskew = True
    cfg.registration.max_num_threads = 1
    cfg.mapping.voxel_size = float(cfg.data.max_range / 100.0)
    return cfg


def run_kiss(export_dir, max_range, first=0):
    """KISS-ICP on every exported sweep from the first-th on. Returns (pose times s, lidar poses
    (n, 4, 4) in that sweep's frame, CPU ms per frame, config dict, notes)."""
    from kiss_icp.kiss_icp import KissICP
    import kiss_icp
    times, files, _ = read_export(export_dir)
    times, files = times[first:], files[first:]
    cfg = kiss_config(max_range)
    odom = KissICP(config=cfg)
    poses, ptimes, cpu_ms, wall_ms = [], [], [], []
    no_time = 0
    t_start = time.monotonic()
    for k, (t0, f) in enumerate(zip(times, files)):
        a = np.fromfile(f, dtype="<f4").reshape(-1, 4)
        pts = a[:, :3].astype(np.float64)
        ts = a[:, 3].astype(np.float64)
        if len(ts) == 0 or ts.max() <= ts.min():
            # no per-point times (deskewed keyframes): KISS-ICP's own loaders pass none then
            ts, t_pose = np.zeros(0), t0
            no_time += 1
        else:
            # KISS-ICP deskews to the sweep's last point (normalised time 1), so its pose is that instant's
            t_pose = t0 + float(ts.max())
        c0, w0 = time.process_time(), time.perf_counter()
        odom.register_frame(pts, ts)
        c1, w1 = time.process_time(), time.perf_counter()
        cpu_ms.append((c1 - c0) * 1e3)
        wall_ms.append((w1 - w0) * 1e3)
        poses.append(odom.last_pose.copy())
        ptimes.append(t_pose)
        if (k + 1) % 200 == 0:
            el = time.monotonic() - t_start
            log(f"  KISS-ICP {k + 1}/{len(files)} frames, {el:.0f} s, median {np.median(cpu_ms):.1f} CPU ms/frame")
    conf = cfg.model_dump()
    conf["kiss_icp_version"] = getattr(kiss_icp, "__version__", "?")
    notes = []
    if no_time:
        notes.append(f"{no_time} of {len(files)} sweeps without per-point times (no deskew possible)")
    return np.array(ptimes), np.array(poses), np.array(cpu_ms), np.array(wall_ms), conf, notes


# ---------------------------------------------------------------- ours

def run_ours(cmd, log_path, out_dir, vehicle):
    out_dir = pathlib.Path(out_dir)
    shutil.rmtree(out_dir, ignore_errors=True)
    args = shlex.split(cmd) + ["--log", str(log_path), "--out", str(out_dir)]
    if vehicle:
        args += ["--vehicle", str(vehicle)]
    log(f"  ours: {' '.join(args)}")
    before = os.times()
    t0 = time.monotonic()
    p = subprocess.run(args, capture_output=True, text=True)
    wall = time.monotonic() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    res = {"command": " ".join(args), "exit": p.returncode, "wall_s_measured": wall, "cpu_s_measured": cpu}
    if p.returncode != 0:
        res["error"] = (p.stderr or p.stdout)[-600:]
        return res
    rep = out_dir / "report.json"
    if rep.exists():
        res["report"] = json.loads(rep.read_text())
    traj = out_dir / "trajectory.tum"
    if not traj.exists():
        res["error"] = f"{traj} not written"
        return res
    res["trajectory"] = tm.read_tum(traj)
    odo = out_dir / "odometry.tum"
    if odo.exists():
        res["odometry"] = tm.read_tum(odo)
    return res


# ---------------------------------------------------------------- scoring

def score(times, poses, ref_times, ref_poses, flagged=None):
    """Metrics of a base trajectory (times, poses) against a reference. flagged (times of
    reference poses not to be believed; a real reference's): also the drift over the segments
    where the reference is a motion a car can make (trajmetrics.possible_spans)."""
    inside, ref = tm.poses_at(ref_times, ref_poses, times)
    est = poses[inside]
    if len(est) < 3:
        return {"error": "fewer than 3 poses inside the reference's time span"}
    if not np.all(np.isfinite(est)):
        return {"error": "non-finite poses"}
    rmse, amax, _ = tm.ate(est, ref)
    scale, amax_sim3 = tm.ate_sim3(est, ref)
    dt, dr, nseg, lengths, per = tm.relative_drift(est, ref)
    out = {"poses": int(len(est)), "poses_outside_reference": int((~inside).sum()),
           "path_m": tm.path_length(ref), "drift_pct": dt, "drift_deg_per_100m": dr, "drift_segments": nseg,
           "drift_lengths_m": lengths, "drift_per_length": {str(k): v for k, v in per.items()},
           "ate_rmse_m": rmse, "ate_max_m": amax, "sim3_scale": scale, "ate_sim3_max_m": amax_sim3}
    if flagged is not None:
        t = times[inside]
        fl = [i for i in range(len(t)) if np.any(np.abs(np.asarray(flagged) - t[i]) < 1e-3)]
        span = tm.possible_spans(t, ref, fl)
        out["drift_possible_pct"], _, out["drift_possible_segments"], _, _ = tm.relative_drift(est, ref, span=span)
        out["reference_possible_poses"] = int(np.sum(span >= 0))
    return out


def timing(cpu_ms, period_s):
    med = float(np.median(cpu_ms))
    mean = float(np.mean(cpu_ms))
    return {"cpu_ms_median": med, "cpu_ms_p99": float(np.percentile(cpu_ms, 99)), "cpu_ms_mean": mean,
            "rtf": period_s * 1e3 / mean if mean > 0 else float("nan")}


def fmt(v, f="{:.2f}"):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f.format(v)


def surface_score(ours_dir, gt_path, site, drive_args):
    """The mapper's map against the simulated world itself (simdrive --surface-distance: the
    drive day's ground and objects, and the drive's road users, known from drive_args: the
    simdrive options the drive was made with), moved into the truth's frame by the alignment
    of its trajectory to GROUND_TRUTH."""
    sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
    import locbench as lb
    t, P = tm.read_tum(ours_dir / "trajectory.tum")
    gt_t, gt_P = tm.read_tum(gt_path)
    ok, G = tm.poses_at(gt_t, gt_P, t)
    R, tr = tm.umeyama_se3(P[ok][:, :3, 3], G[:, :3, 3])
    pts = lb.read_pcd(ours_dir / "map.pcd")[:, :3].astype(float) @ R.T + tr
    f = ours_dir / "map_in_truth.f32"
    pts.astype("<f4").tofile(f)
    p = sh([BIN / "simdrive", "--site", site, *drive_args, "--surface-distance", f])
    f.unlink()
    return json.loads(p.stdout)


def bench_drive(name, log_path, vehicle, sensor_range, gt_label, extra_refs, args, result, world=None, gt_real=False):
    """Scores against the log's GROUND_TRUTH (labelled gt_label) and extra_refs(base_from_lidar),
    a list of more (label, times, base poses, flagged: see score). gt_real: GROUND_TRUTH is a
    real reference (an estimate): scored also where it is a motion a car can make."""
    d = OUT / name
    d.mkdir(parents=True, exist_ok=True)
    log(f"[{name}] exporting scans of {log_path} ...")
    ex = export(log_path, d / "export", vehicle)
    times, files, B = read_export(ex)
    period = float(np.median(np.diff(times))) if len(times) > 1 else float("nan")
    gt_path = ex / "ground_truth.tum"
    if not gt_path.exists():
        raise RuntimeError(f"{log_path}: no GROUND_TRUTH to score against")
    refs = [(gt_label,) + tm.read_tum(gt_path) + (() if gt_real else None,)] + (extra_refs(B) if extra_refs else [])
    drive = {"log": str(log_path), "scans": len(times), "scan_period_s": period, "base_from_lidar": B.tolist(),
             "references": [r[0] for r in refs], "methods": {}}
    result["drives"][name] = drive

    # KISS-ICP (on a short drive as many times as ours, each run just before one of ours, so that
    # both meet the shared host in the same state: the median run's time of each)
    short = len(files) <= SHORT_DRIVE_SWEEPS
    kruns = args.runs if short else 1
    log(f"[{name}] KISS-ICP on {len(files)} sweeps (one thread{f', {kruns} runs, each before one of ours' if kruns > 1 else ''}) ...")
    kiss = [run_kiss(ex, args.kiss_max_range or sensor_range)]
    kt, kposes, cpu_ms, wall_ms, conf, notes = kiss[0]
    # lidar poses in the first sweep's frame -> base poses in map, anchored at the reference's
    # first pose (the scores align or use relative motion, so the anchor only makes files readable)
    ref0_t, ref0_P = refs[0][1], refs[0][2]
    ok0, A = tm.poses_at(ref0_t, ref0_P, kt[:1])
    anchor = (A[0] if ok0[0] else np.eye(4)) @ B
    kbase = anchor @ kposes @ np.linalg.inv(B)
    tm.write_tum(d / "kiss_icp.tum", kt, kbase)
    k = {"config": conf, "notes": notes, "threads": "registration.max_num_threads=1, OMP_NUM_THREADS=1",
         "pose_time": "end of sweep (utime + last point's time): KISS-ICP deskews to the sweep's last point",
         "wall_ms_median": float(np.median(wall_ms)), **timing(cpu_ms, period), "scores": {}}
    for label, rt, rp, fl in refs:
        k["scores"][label] = score(kt, kbase, rt, rp, fl)
    drive["methods"]["kiss_icp"] = k

    # ours: on the LiDAR alone (KISS-ICP's input; GNSS_FIX stays for the anchoring), and, when
    # the log has the car's IMU, with the IMU and VEHICLE_SPEED (the can driver's, merged in)
    log(f"[{name}] ours ...")
    lidar_log = d / "lidar_only.lcm"
    sh([BIN / "log-merge", "--quiet", "--out", lidar_log, "--drop", "IMU", "--drop", "VEHICLE_SPEED",
        "--drop", "CAN_FRAME", log_path])
    before = (lambda i: kiss.append(run_kiss(ex, args.kiss_max_range or sensor_range)) if 0 < i < kruns else None)
    ores = run_and_score(lidar_log, d / "ours", vehicle, refs, period, args.runs if world or short else 1, before)
    drive["methods"]["ours"] = ores
    kmeans = [float(np.mean(r[2])) for r in kiss]
    _, _, cpu_ms, wall_ms, _, _ = kiss[int(np.argsort(kmeans)[len(kmeans) // 2])]
    k.update(runs=len(kiss), cpu_ms_mean_runs=kmeans, wall_ms_median=float(np.median(wall_ms)), **timing(cpu_ms, period))
    if any(not np.array_equal(r[1], kposes) for r in kiss[1:]):
        notes.append("KISS-ICP's runs gave different poses: the first run's are scored")
    lidar_log.unlink(missing_ok=True)
    fused = fused_log(log_path, d)
    if fused:
        log(f"[{name}] ours with IMU and VEHICLE_SPEED ...")
        drive["methods"]["ours_fused"] = run_and_score(fused, d / "ours_fused", vehicle, refs, period)
    if world and "error" not in ores:
        log(f"[{name}] the map against the simulated world ...")
        drive["map_vs_world"] = surface_score(d / "ours", gt_path, *world)
    k = drive["methods"]["kiss_icp"]
    if "cpu_ms_mean" in ores:
        drive["ours_speedup_vs_kiss_icp"] = k["cpu_ms_mean"] / ores["cpu_ms_mean"]
    if not args.keep_scans:
        shutil.rmtree(ex / "scans", ignore_errors=True)
        (ex / "times.txt").unlink(missing_ok=True)   # so the next run exports again


def channels_of(log_path, wanted):
    """Which of the channels in `wanted` the log has (read until all are seen)."""
    seen = set()
    for ev in lcm.EventLog(str(log_path), "r"):
        if ev.channel in wanted:
            seen.add(ev.channel)
            if seen == wanted:
                break
    return seen


def fused_log(log_path, d):
    """The log with IMU and VEHICLE_SPEED: itself if it has both, else with VEHICLE_SPEED
    merged in (can --replay of its CAN_FRAME) if it has IMU and CAN_FRAME; None otherwise."""
    out = d / "fused.lcm"
    if newer(out, log_path, BIN / "can", BIN / "log-merge"):
        return out
    has = channels_of(log_path, {"IMU", "VEHICLE_SPEED", "CAN_FRAME"})
    if "IMU" not in has:
        return None
    if "VEHICLE_SPEED" in has:
        return log_path
    if "CAN_FRAME" not in has:
        return None
    sh([BIN / "can", "--replay", log_path, "--out", d / "speed.lcm"])
    sh([BIN / "log-merge", "--quiet", "--out", out, log_path, d / "speed.lcm"])
    return out


def output_digests(out_dir):
    """SHA-256 of every file the mapper wrote but report.json (which holds its times)."""
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(pathlib.Path(out_dir).iterdir()) if f.is_file() and f.name != "report.json"}


def run_and_score(log_path, out_dir, vehicle, refs, period, runs=1, before=None):
    """The mapper on log_path into out_dir (runs times: the median wall time, and the files of
    every run compared with the first's; before(i), if given, called before run i), its timing
    and its scores against refs."""
    walls, cpus, digests, differ = [], [], None, []
    for i in range(runs):
        if before:
            before(i)
        o = run_ours(str(BIN / "mapper"), log_path, out_dir, vehicle)
        if "error" in o:
            break
        walls.append(o["report"]["wall_s"])
        cpus.append(o["report"]["cpu_s_odometry"])
        d = output_digests(out_dir)
        if digests is None:
            digests = d
        elif d != digests:
            differ.append(f"run {i + 1}: " + ", ".join(sorted(k for k in set(d) | set(digests)
                                                                 if d.get(k) != digests.get(k))))
    rep = o.get("report", {})
    ores = {k2: v for k2, v in o.items() if k2 not in ("trajectory", "odometry")}
    if "error" in o:
        return ores
    ores["runs"] = runs
    ores["wall_s_runs"] = walls
    ores["cpu_s_odometry_runs"] = cpus
    ores["runs_identical"] = not differ
    ores["runs_differ"] = differ
    n = rep["scans"]
    # the median is the main thread's CPU per sweep; the mean counts the thread that builds
    # the registration maps too, which is the figure to compare with KISS-ICP's mean
    ores["cpu_ms_median"] = rep["cpu_ms_per_scan_median"]
    ores["cpu_ms_p99"] = rep["cpu_ms_per_scan_p99"]
    ores["cpu_ms_mean"] = float(np.median(cpus)) * 1e3 / n
    ores["rtf"] = period * 1e3 / ores["cpu_ms_mean"]
    ores["whole_mapper_rtf_wall"] = rep["drive_s"] / float(np.median(walls))
    ores["scores"] = {}
    for label, rt, rp, fl in refs:
        s = score(*o["trajectory"], rt, rp, fl)
        if "odometry" in o:   # drift before loop closure
            so = score(*o["odometry"], rt, rp, fl)
            s["after_loop_closure"] = {kk: s.get(kk) for kk in ("drift_pct", "drift_deg_per_100m", "drift_possible_pct")}
            s["drift_pct"], s["drift_deg_per_100m"] = so.get("drift_pct"), so.get("drift_deg_per_100m")
            if "drift_possible_pct" in so:
                s["drift_possible_pct"] = so["drift_possible_pct"]
            s["odometry_ate_rmse_m"] = so.get("ate_rmse_m")
            s["drift_from"] = "odometry.tum (before loop closure)"
        else:
            s["drift_from"] = "trajectory.tum (odometry only: no loop closure yet)"
        ores["scores"][label] = s
    return ores


MULRAN_STARTS = (0, 6, 12, 20, 30, 45, 64, 80, 96, 110, 120, 140)


def steps_agreeing(times, poses, ref_times, ref_poses, implausible, tol_m=0.3, tol_deg=1.0):
    """(agreeing, counted): the steps between consecutive poses whose relative motion lies
    within tol_m and tol_deg of the reference's, leaving out steps from or to a keyframe the
    reference itself makes implausible."""
    inside, ref = tm.poses_at(ref_times, ref_poses, times)
    est, t = poses[inside], times[inside]
    idx = [int(np.argmin(np.abs(ref_times - x))) for x in t]
    ok = n = 0
    for i in range(1, len(est)):
        if idx[i] in implausible or idx[i - 1] in implausible:
            continue
        d = np.linalg.inv(np.linalg.inv(ref[i - 1]) @ ref[i]) @ (np.linalg.inv(est[i - 1]) @ est[i])
        n += 1
        ok += bool(np.linalg.norm(d[:3, 3]) < tol_m and tm.rot_angle(d[:3, :3]) * 180 / np.pi < tol_deg)
    return ok, n


def starts_on_real_scans(log_path, vehicle, refined, result, keep_scans=False):
    """One run from the drive's start says little on keyframes this sparse: where a method
    loses the car's speed it stays lost, and where it is lost depends on where it began. Ours
    and KISS-ICP from each of MULRAN_STARTS: the share of steps that agree with the refined
    reference, and the drift."""
    rep_path = refined.parent / "reference-report.json"
    d = OUT / "mulran" / "starts"
    drive = result["drives"]["mulran"]
    if not refined.exists() or not rep_path.exists():
        drive["notes"].append("starts: no refined reference (make bench-localizer-real)")
        return
    implausible = set(json.loads(rep_path.read_text())["implausible_keyframes_refined"])
    ex = export(log_path, OUT / "mulran" / "export", vehicle)
    _, files, B = read_export(ex)
    ref_label, ref_t, ref_P, ref_fl = mulran_refined_reference(B, refined)[0]
    events = list(lcm.EventLog(str(log_path), "r"))
    scan_utimes = [ev.timestamp for ev in events if ev.channel == "LIDAR_SCAN"]
    rows = []
    for k in MULRAN_STARTS:
        if k >= len(files) - 10:
            continue
        log(f"[mulran] from keyframe {k}: ours and KISS-ICP ...")
        d.mkdir(parents=True, exist_ok=True)
        cut = d / f"from_{k}.lcm"
        w = lcm.EventLog(str(cut), "w", overwrite=True)
        for ev in events:
            if ev.timestamp >= scan_utimes[k] - 1:
                w.write_event(ev.timestamp, ev.channel, ev.data)
        w.close()
        o = run_ours(str(BIN / "mapper"), cut, d / f"ours_{k}", vehicle)
        cut.unlink()
        row = {"from_keyframe": k}
        if "error" in o:
            row["ours_error"] = o["error"]
        else:
            ot, oP = o["odometry"] if "odometry" in o else o["trajectory"]
            row["ours_steps_agreeing"], row["steps"] = steps_agreeing(ot, oP, ref_t, ref_P, implausible)
            so = score(ot, oP, ref_t, ref_P, ref_fl)
            row["ours_drift_pct"], row["ours_drift_possible_pct"] = so["drift_pct"], so["drift_possible_pct"]
        kt, kp, _, _, _, _ = run_kiss(ex, OS1_64_RANGE_M, first=k)
        kb = kp @ np.linalg.inv(B)
        row["kiss_steps_agreeing"], _ = steps_agreeing(kt, kb, ref_t, ref_P, implausible)
        sk = score(kt, kb, ref_t, ref_P, ref_fl)
        row["kiss_drift_pct"], row["kiss_drift_possible_pct"] = sk["drift_pct"], sk["drift_possible_pct"]
        rows.append(row)
    if not keep_scans:
        shutil.rmtree(ex / "scans", ignore_errors=True)
        (ex / "times.txt").unlink(missing_ok=True)
    tot = lambda key: sum(r.get(key, 0) for r in rows)
    drive["starts"] = {"reference": ref_label, "tolerance": "0.3 m and 1 degree of the reference's step",
                       "implausible_keyframes_left_out": sorted(implausible), "rows": rows,
                       "ours_share": tot("ours_steps_agreeing") / max(tot("steps"), 1),
                       "kiss_share": tot("kiss_steps_agreeing") / max(tot("steps"), 1)}


def carving_on_real_scans(log_path, refined, result):
    """The odometry does not hold on the MulRan keyframes, so the carving of real scans is
    shown with the refined reference's poses (mapper --poses): report.png, the carved points in
    magenta, is the picture to inspect."""
    refs = mulran_refined_reference(np.eye(4), refined)
    if not refs:
        result["drives"]["mulran"]["notes"].append("carving on real scans: no refined reference (make bench-localizer-real)")
        return
    B = np.array(result["drives"]["mulran"]["base_from_lidar"])
    _, times, lidar_poses, _ = refs[0]
    d = OUT / "mulran"
    tm.write_tum(d / "refined_base.tum", times, lidar_poses @ np.linalg.inv(B))
    out = d / "given_poses"
    shutil.rmtree(out, ignore_errors=True)
    sh([BIN / "mapper", "--log", log_path, "--out", out, "--vehicle", ROOT / "vehicles" / "lidar_mast.yaml",
        "--poses", d / "refined_base.tum", "--quiet"])
    rep = json.loads((out / "report.json").read_text())
    result["drives"]["mulran"]["carving_with_refined_poses"] = {
        "map_points": rep["map_points"], "carved": rep["map_points_carved"], "picture": str(out / "report.png")}
    result["drives"]["mulran"]["notes"].append(
        f"carving on real scans (the refined reference's poses, mapper --poses): {rep['map_points_carved']:,} of "
        f"{rep['map_points'] + rep['map_points_carved']:,} points carved; inspect {out / 'report.png'} (magenta)")


# ---------------------------------------------------------------- GNSS holding a drift

HOLD_DRIFT = (0.005, 0.003)   # degrees of yaw a metre (0.5 per 100 m) and scale: an odometry that drifts


def gnss_hold(log_path, result):
    """The loop's GROUND_TRUTH given to the mapper (--poses), once as it is and once turned
    by HOLD_DRIFT: the rigid GNSS fit alone (odometry.tum) against the fit and the hold
    (trajectory.tum), horizontal error against the truth in the site's frame."""
    import yaml
    d = OUT / "sim" / "gnss_hold"
    d.mkdir(parents=True, exist_ok=True)
    sh([BIN / "pose-to-tum", "--log", log_path, "--out", d / "gt.tum", "--channel", "GROUND_TRUTH"])
    t, P = tm.read_tum(d / "gt.tum")
    t, P = t[::10], P[::10]
    turn, scale = HOLD_DRIFT
    Q = [P[0]]
    for a, b in zip(P[:-1], P[1:]):
        step = np.linalg.inv(a) @ b
        step[:3, 3] *= 1 + scale
        c, s_ = np.cos(np.radians(turn * np.linalg.norm(step[:3, 3]))), np.sin(np.radians(turn * np.linalg.norm(step[:3, 3])))
        R = np.eye(4)
        R[:2, :2] = [[c, -s_], [s_, c]]
        Q.append(Q[-1] @ step @ R)
    tm.write_tum(d / "drifted.tum", t, np.array(Q))
    tm.write_tum(d / "truth.tum", t, P)
    default = yaml.safe_load((ROOT / "maps" / "default" / "site.yaml").read_text())["georef"]
    rows = []
    for name in ("truth", "drifted"):
        out = d / name
        shutil.rmtree(out, ignore_errors=True)
        sh([BIN / "mapper", "--log", log_path, "--out", out, "--poses", d / f"{name}.tum", "--quiet"])
        rep = json.loads((out / "report.json").read_text())
        S = tm.site_from_site(default, yaml.safe_load((out / "site.yaml").read_text())["georef"])
        row = {"given": name, "ratio": rep["gnss_drift_ratio"], "held": rep["gnss_held"],
               "max_change_m": rep["gnss_held_max_change_m"], "fixes": rep["gnss_held_fixes"]}
        for f, label in (("odometry", "rigid"), ("trajectory", "held")):
            tt, X = tm.read_tum(out / f"{f}.tum")
            ok, G = tm.poses_at(t, P, tt)
            e = np.linalg.norm((S @ X[ok])[:, :2, 3] - G[:, :2, 3], axis=1)
            row[f"{label}_max_m"], row[f"{label}_rms_m"] = float(e.max()), float(np.sqrt(np.mean(e ** 2)))
        rows.append(row)
    result["gnss_hold"] = {"drift_deg_per_m": turn, "scale": scale, "rows": rows}


def print_hold_table(result):
    h = result.get("gnss_hold")
    if not h:
        return
    print(f"GNSS holding a drift (the loop's GROUND_TRUTH given with --poses, as it is and turned "
          f"{h['drift_deg_per_m'] * 100:g} deg a 100 m with {h['scale'] * 100:g} % scale error); horizontal error "
          f"against the truth, m:")
    cols = [("given", "<8", "given", "{}"), ("ratio", ">6", "ratio", "{:.2f}"), ("held", ">5", "held", "{}"),
            ("rigid max", ">9", "rigid_max_m", "{:.2f}"), ("rigid rms", ">9", "rigid_rms_m", "{:.2f}"),
            ("held max", ">8", "held_max_m", "{:.2f}"), ("held rms", ">8", "held_rms_m", "{:.2f}")]
    hdr = " ".join(f"{name:{align}}" for name, align, _, _ in cols)
    print(hdr + "\n" + "-" * len(hdr))
    for r in h["rows"]:
        print(" ".join(f"{f.format(r[key]):{align}}" for _, align, key, f in cols))
    print()


# ---------------------------------------------------------------- the localizer on the map

LOC_DRIVES = [(1, "normal"), (2, "aggressive"), (3, "cautious")]   # 30 s each, as bench-localizer-drive's


def localize_on_mapped_map(drive_log, ours_dir, result):
    """The localizer (fused, GNSS start) on three other drives of the loop, with the default
    site and with the mapper's own site (its map.pcd and the site.yaml of its GNSS
    anchoring), in the same run. Poses on the mapper's site are in its frame; they are
    scored against GROUND_TRUTH through the rigid alignment of the mapper's trajectory to
    the truth (how well the car is placed in the map, which is what a study staged on that
    map needs); how far the GNSS anchoring put that frame from the truth's is reported
    apart (anchoring)."""
    sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
    import locbench as lb
    import yaml
    site = ours_dir
    if not (site / "site.yaml").exists():
        raise RuntimeError(f"{site}: no site.yaml (the mapper did not geo-reference the map)")
    t, P = tm.read_tum(ours_dir / "trajectory.tum")
    gt_t, gt_P = tm.read_tum(OUT / "sim" / "export" / "ground_truth.tum")
    ok, G = tm.poses_at(gt_t, gt_P, t)
    R, tr = tm.umeyama_se3(P[ok][:, :3, 3], G[:, :3, 3])   # truth frame <- mapper frame
    truth_from_map = np.eye(4)
    truth_from_map[:3, :3], truth_from_map[:3, 3] = R, tr
    # anchoring: the frame the geo-references give against the one the truth gives, at the drive
    default = yaml.safe_load((ROOT / "maps" / "default" / "site.yaml").read_text())["georef"]
    mine = yaml.safe_load((site / "site.yaml").read_text())["georef"]
    by_georef = tm.site_from_site(default, mine)
    c = P[ok][:, :3, 3].mean(axis=0)
    off = by_georef[:3, :3] @ c + by_georef[:3, 3] - (R @ c + tr)
    dyaw = np.degrees(np.arctan2(by_georef[1, 0], by_georef[0, 0]) - np.arctan2(R[1, 0], R[0, 0]))
    anchoring = {"horizontal_m": float(np.linalg.norm(off[:2])), "vertical_m": float(off[2]),
                 "yaw_deg": float((dyaw + 180) % 360 - 180)}
    yaw_of = np.arctan2(R[1, 0], R[0, 0])
    rows = []
    for seed, profile in LOC_DRIVES:
        d = OUT / "loc" / f"s{seed}_{profile}_30"
        d.mkdir(parents=True, exist_ok=True)
        cache = ROOT / "build" / "bench-localizer-drive" / f"s{seed}_{profile}_30" / "input.lcm"
        inp = cache if lb.cached(cache) else lb.make_drive(d, seed, profile, 30)
        gt = lb.read_poses(inp, "GROUND_TRUTH")
        for label, site_dir in (("default site", ROOT / "maps" / "default"), ("mapper's site", site)):
            out = d / ("out_default.lcm" if site_dir != site else "out_mapped.lcm")
            log(f"  localizer on {inp.parent.name} with the {label} ...")
            p = lb.run_localizer(inp, out, ["--site", site_dir])
            if p.returncode != 0:
                raise RuntimeError(f"localizer on {inp}: exit {p.returncode}\n{p.stderr[-1500:]}")
            poses = lb.read_poses(out, "POSE")
            if site_dir == site and len(poses):   # into the truth's frame by the alignment above
                xyz = poses[:, 1:4] @ R.T + tr
                poses = np.column_stack([poses[:, 0], xyz, poses[:, 4] + yaw_of, poses[:, 5]])
            tracking = poses[:, 5] == 1
            r = {"poses": int(len(poses)), "tracking": int(tracking.sum()), "lost": int((poses[:, 5] == 3).sum()),
                 "first_tracking_s": float((poses[np.argmax(tracking), 0] - poses[0, 0]) * 1e-6) if tracking.any()
                 else float("nan")}
            _, et, ey = lb.errors_vs_truth(poses[tracking], gt)
            if len(et):
                r.update(t_median=float(np.median(et)), t_p99=float(np.percentile(et, 99)), t_max=float(et.max()),
                         yaw_p99=float(np.percentile(ey, 99)))
            rows.append({"drive": f"seed {seed} {profile} 30 s", "map": label, **r})
    pts = lb.read_pcd(site / "map.pcd")
    result["localizer_on_mapped_map"] = {"mapping_drive": str(drive_log), "truth_from_map": truth_from_map.tolist(),
                                         "anchoring": anchoring, "map_points": int(len(pts)), "rows": rows}


def print_localizer_table(result):
    lm = result.get("localizer_on_mapped_map")
    if not lm:
        return
    a = lm["anchoring"]
    print(f"GNSS anchoring of the mapper's site (its site.yaml against the truth's frame): horizontal "
          f"{a['horizontal_m']:.2f} m, vertical {a['vertical_m']:+.2f} m, yaw {a['yaw_deg']:+.3f} deg")
    print(f"The localizer (fused, GNSS start) on other drives of the loop, on the default site and on the "
          f"mapper's ({lm['map_points']:,} points, from {pathlib.Path(lm['mapping_drive']).parent.name}; errors in "
          f"the map, through the alignment of the mapper's trajectory to the truth):")
    hdr = f"{'drive':<26} {'map':<18} {'median m':>8} {'p99 m':>7} {'max m':>7} {'yaw p99':>7} {'LOST':>4} {'init s':>6}"
    print(hdr)
    print("-" * len(hdr))
    for r in lm["rows"]:
        print(f"{r['drive']:<26} {r['map']:<18} {fmt(r.get('t_median'), '{:.3f}'):>8} {fmt(r.get('t_p99'), '{:.3f}'):>7} "
              f"{fmt(r.get('t_max'), '{:.3f}'):>7} {fmt(r.get('yaw_p99'), '{:.3f}'):>7} "
              f"{r.get('lost', '-'):>4} {fmt(r.get('first_tracking_s'), '{:.1f}'):>6}")
    print()


def whole_mapper_wall(o):
    """The whole mapper's real-time factor, its runs, whether their files agreed, its steps."""
    text = f"{o['whole_mapper_rtf_wall']:.1f} x real time (wall"
    if o.get("runs", 1) > 1:
        same = ("files the same byte for byte" if o["runs_identical"]
                else "files NOT the same: " + "; ".join(o["runs_differ"]))
        text += f", median of {o['runs']} runs: " + " / ".join(f"{w:.1f}" for w in o["wall_s_runs"]) + f" s; their {same}"
    text += ")"
    steps = o.get("report", {}).get("wall_s_steps")
    if steps:
        text += "; the last run's steps: " + ", ".join(f"{k} {v:.1f} s" for k, v in steps.items())
    return text


def print_table(result):
    hdr = (f"{'drive':<8} {'reference':<26} {'method':<10} {'scans':>5} {'path m':>7} {'drift %':>7} {'deg/100m':>8} "
           f"{'ATE rmse':>8} {'ATE max':>8} {'scale':>7} {'sim3 max':>8} {'ms med':>7} {'ms p99':>7} {'ms mean':>7} {'RTF':>6}")
    print(hdr)
    print("-" * len(hdr))
    for dname, drv in result["drives"].items():
        for label in drv["references"]:
            for mname, m in drv["methods"].items():
                if "error" in m:
                    print(f"{dname:<8} {label:<26} {mname:<10} failed: {m['error'].strip().splitlines()[-1][:80]}")
                    continue
                s = m["scores"][label]
                if "error" in s:
                    print(f"{dname:<8} {label:<26} {mname:<10} {s['error']}")
                    continue
                print(f"{dname:<8} {label:<26} {mname:<10} {s['poses']:>5} {s['path_m']:>7.0f} {fmt(s['drift_pct']):>7} "
                      f"{fmt(s['drift_deg_per_100m'], '{:.3f}'):>8} {fmt(s['ate_rmse_m'], '{:.3f}'):>8} "
                      f"{fmt(s['ate_max_m'], '{:.3f}'):>8} {fmt(s.get('sim3_scale'), '{:.5f}'):>7} "
                      f"{fmt(s.get('ate_sim3_max_m'), '{:.3f}'):>8} {fmt(m.get('cpu_ms_median'), '{:.1f}'):>7} "
                      f"{fmt(m.get('cpu_ms_p99'), '{:.1f}'):>7} {fmt(m.get('cpu_ms_mean'), '{:.1f}'):>7} "
                      f"{fmt(m.get('rtf'), '{:.2f}'):>6}")
    print()
    for dname, drv in result["drives"].items():
        o = drv["methods"].get("ours", {})
        if "ours_speedup_vs_kiss_icp" in drv:
            print(f"{dname}: ours {drv['ours_speedup_vs_kiss_icp']:.1f} x faster than KISS-ICP (mean CPU per sweep, "
                  f"{o['cpu_ms_mean']:.1f} ms with the map-building thread vs {drv['methods']['kiss_icp']['cpu_ms_mean']:.1f} ms); "
                  f"the whole mapper (odometry and map.pcd, 2 threads) {whole_mapper_wall(o)}")
        mw = drv.get("map_vs_world")
        if mw:
            print(f"{dname}: the map against the simulated world: {mw['points']:,} points, {100 * mw['within_0.05']:.1f} % "
                  f"within 5 cm of a true static surface (target 95 %), median {mw['median_m'] * 1000:.1f} mm, "
                  f"{100 * mw['beyond_0.5']:.2f} % farther than 0.5 m ({mw['beyond_0.5_on_moving']:,} of them on moving "
                  f"objects, {mw['beyond_0.5_on_own_body']:,} on the car's own body, {mw['beyond_0.5_other']:,} other); "
                  f"points on moving objects: {mw['on_moving']:,} ({100 * mw['on_moving_share']:.3f} %, target 0)")
        for label in drv["references"]:
            row = {m: drv["methods"][m]["scores"][label].get("drift_possible_pct") for m in drv["methods"]
                   if "scores" in drv["methods"][m]}
            if any(v is not None for v in row.values()):
                s0 = next(drv["methods"][m]["scores"][label] for m in row)
                print(f"{dname}: drift where {label} is a motion a car can make ({s0.get('reference_possible_poses')} of "
                      f"{s0['poses']} poses; no sliding sideways or running backwards over 2 m/s, no 5 m/s^2, none it "
                      f"flags): " + ", ".join(f"{m} {fmt(v, '{:.1f}')} %" for m, v in row.items()))
        for line in drv.get("notes", []):
            print(f"{dname}: {line}")
        st = drv.get("starts")
        if st:
            print(f"{dname}: from {len(st['rows'])} starts, the steps within {st['tolerance']} ({st['reference']}; "
                  f"keyframes it makes implausible left out):")
            print(f"  {'from keyframe':>13} {'steps':>5} {'ours':>6} {'KISS-ICP':>8} {'ours drift %':>12} {'KISS drift %':>12} "
                  f"{'(where possible: ours':>21} {'KISS-ICP)':>9}")
            for r in st["rows"]:
                if "ours_error" in r:
                    print(f"  {r['from_keyframe']:>13} ours failed: {r['ours_error'].strip().splitlines()[-1][:80]}")
                    continue
                print(f"  {r['from_keyframe']:>13} {r['steps']:>5} {r['ours_steps_agreeing']:>6} {r['kiss_steps_agreeing']:>8} "
                      f"{fmt(r['ours_drift_pct'], '{:.1f}'):>12} {fmt(r['kiss_drift_pct'], '{:.1f}'):>12} "
                      f"{fmt(r.get('ours_drift_possible_pct'), '{:.1f}'):>21} {fmt(r.get('kiss_drift_possible_pct'), '{:.1f}'):>9}")
            print(f"  {'all':>13} {'':>5} {100 * st['ours_share']:>5.1f}% {100 * st['kiss_share']:>7.1f}%")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Writes build/bench/mapper.json; work files in build/bench/mapper/.")
    ap.add_argument("--drives", default="sim,trees,hills,mulran",
                    help="comma-separated: sim, trees, hills, mulran (default all)")
    ap.add_argument("--sim-log", help="the simulated loop's log (default: the bench-localizer-drive cache, else simulated)")
    ap.add_argument("--sim-args", default=shlex.join(SIM_ARGS),
                    help="the simdrive options the loop's log was made with (they place its road users for the "
                         "points on moving objects; default: those of the cached or simulated loop, %(default)s)")
    ap.add_argument("--refined", default=str(REFINED),
                    help="MulRan refined reference (default: bench-localizer-real's, if it made one)")
    ap.add_argument("--kiss-max-range", type=float,
                    help="KISS-ICP data.max_range in m instead of the sensor's range (120 m on both drives; "
                         "KISS-ICP's own default is 100 m)")
    ap.add_argument("--runs", type=int, default=3,
                    help="runs of ours (LiDAR alone) on each simulated drive and on drives of 600 sweeps or fewer "
                         "(KISS-ICP too on those): the median wall time and CPU time, the files compared "
                         "(default %(default)s)")
    ap.add_argument("--keep-scans", action="store_true", help="keep the exported scans (about 1.9 GB for the loop)")
    ap.add_argument("--json", default=str(JSON_OUT), help=f"output JSON (default {JSON_OUT.relative_to(ROOT)})")
    args = ap.parse_args()
    try:
        import kiss_icp  # noqa: F401
    except ImportError as e:
        sys.exit(f"bench_mapper: kiss-icp is not installed in {sys.executable}'s environment ({e}): make deps")
    if args.runs < 1:
        sys.exit(f"bench_mapper: --runs {args.runs}: at least 1")
    drives = [x.strip() for x in args.drives.split(",") if x.strip()]
    unknown = set(drives) - {"sim", "trees", "hills", "mulran"}
    if unknown:
        sys.exit(f"bench_mapper: --drives: unknown drive(s) {', '.join(sorted(unknown))}; "
                 "expected sim, trees, hills, mulran")
    need = ["mapper", "scan-export"] + (["import-scans"] if "mulran" in drives and MULRAN.is_dir() else []) + \
        (["simdrive"] if ("sim" in drives and not args.sim_log and not SIM_CACHED.exists()) or "hills" in drives
         or "trees" in drives else [])
    for b in need:
        if not (BIN / b).exists():
            sys.exit(f"bench_mapper: {BIN / b} is missing: make {BIN / b}")
    import kiss_icp
    result = {"date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
              "host": platform.node(), "cpus": os.cpu_count(), "load_avg_start": os.getloadavg(),
              "kiss_icp_version": getattr(kiss_icp, "__version__", "?"), "drives": {}}
    if "sim" in drives:
        log_path, how = sim_drive(args.sim_log)
        bench_drive("sim", log_path, ROOT / "vehicles" / "prius2017.yaml", SIM_SENSOR_RANGE_M, "GROUND_TRUTH", None,
                    args, result, world=(ROOT / "maps" / "default", shlex.split(args.sim_args)))
        result["drives"]["sim"]["source"] = how
        if "error" not in result["drives"]["sim"]["methods"]["ours"]:
            log("[sim] the localizer on the mapper's map ...")
            localize_on_mapped_map(log_path, OUT / "sim" / "ours", result)
        log("[sim] GNSS holding a drifted trajectory ...")
        gnss_hold(log_path, result)
    if "trees" in drives:
        log_path, site, targs = trees_drive()
        bench_drive("trees", log_path, ROOT / "vehicles" / "prius2017.yaml", SIM_SENSOR_RANGE_M, "GROUND_TRUTH", None,
                    args, result, world=(site, targs))
        result["drives"]["trees"]["source"] = f"simdrive --site {site} {' '.join(targs)}"
        result["drives"]["trees"]["notes"] = [
            "the map against the world: a canopy's points lie inside it (where the beams stopped), not on "
            "its surface, and count as off it: 'within 5 cm' and 'other farther than 0.5 m' are no measure of "
            "the map here (the target's drives are sim and hills); the points on moving objects are"]
    if "hills" in drives:
        bench_drive("hills", hills_drive(), ROOT / "vehicles" / "prius2017.yaml", SIM_SENSOR_RANGE_M, "GROUND_TRUTH",
                    None, args, result, world=(ROOT / "maps" / "hills", HILLS_ARGS))
    if "mulran" in drives:
        if not MULRAN.is_dir():
            print(f"mulran: skipped, {MULRAN} is absent")
        else:
            log_path = mulran_drive()
            bench_drive("mulran", log_path, ROOT / "vehicles" / "lidar_mast.yaml", OS1_64_RANGE_M,
                        "dataset poses (SLAM est.)",
                        lambda B: mulran_refined_reference(B, pathlib.Path(args.refined)), args, result, gt_real=True)
            result["drives"]["mulran"]["notes"] = [
                "reference = the dataset's FAST-LIO2 + SC-PGO poses: a SLAM estimate, not ground truth",
                "keyframes 0.5-5.5 s apart (median 0.5 s), deskewed and downsampled already: no per-point times; "
                "RTF is against the keyframe spacing, the sensor itself runs at 10 Hz"]
            carving_on_real_scans(log_path, pathlib.Path(args.refined), result)
            starts_on_real_scans(log_path, ROOT / "vehicles" / "lidar_mast.yaml", pathlib.Path(args.refined), result,
                                 args.keep_scans)
    result["load_avg_end"] = os.getloadavg()
    mr = f"{args.kiss_max_range:g} m" if args.kiss_max_range else "the sensor's range"
    print(f"bench-mapper: KISS-ICP {result['kiss_icp_version']} (Python API, default config, max_range = {mr}, "
          f"deskew on, one thread) vs ours; drift = KITTI relative drift over 100..800 m segments; ATE after SE(3) "
          f"alignment; CPU ms per frame; RTF = scan period / mean CPU per frame")
    print_table(result)
    print_localizer_table(result)
    print_hold_table(result)
    pathlib.Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(args.json).write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"written {args.json}")
    differ = [n for n, d in result["drives"].items() if not d["methods"].get("ours", {}).get("runs_identical", True)]
    if differ:
        sys.exit(f"bench_mapper: the mapper's runs on {', '.join(differ)} did not write the same files")


if __name__ == "__main__":
    main()
