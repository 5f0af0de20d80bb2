"""Helpers shared by the localizer benchmark (bench_drive.py) and tests/test_localizer.py:
simulate a drive, add VEHICLE_SPEED (can --replay + log-merge), run the localizer on it,
and score its POSE against GROUND_TRUTH."""
import csv
import math
import os
import pathlib
import subprocess
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[3]
BIN = ROOT / "build" / "bin"
sys.path.insert(0, str(ROOT / "build" / "python"))

import lcm  # noqa: E402
from portobello import pose_t  # noqa: E402

STATUS = {0: "initializing", 1: "tracking", 2: "degraded", 3: "lost"}


def read_pcd(path):
    """A binary PCD of x y z intensity (float32), as the map tools write it: an (n, 4) array."""
    with open(path, "rb") as f:
        n = 0
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: no DATA line")
            if line.startswith(b"POINTS"):
                n = int(line.split()[1])
            if line.startswith(b"DATA"):
                if b"binary" not in line:
                    raise ValueError(f"{path}: {line.decode().strip()}: binary expected")
                break
        return np.frombuffer(f.read(n * 16), dtype="<f4").reshape(n, 4)


def write_pcd(path, pts):
    """Writes an (n, 4) array of x y z intensity as a binary PCD."""
    with open(path, "wb") as f:
        f.write(("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\n"
                 "TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA binary\n"
                 % (len(pts), len(pts))).encode())
        f.write(pts.astype("<f4").tobytes())


def crop_map(src_pcd, gt, dst_pcd, margin):
    """The map cropped to a drive's surroundings (gt: rows of utime, x, y...; margin in metres):
    a start's map then loads in about a second."""
    pts = read_pcd(src_pcd)
    lo, hi = gt[:, 1:3].min(0) - margin, gt[:, 1:3].max(0) + margin
    write_pcd(dst_pcd, pts[(pts[:, 0] > lo[0]) & (pts[:, 0] < hi[0]) & (pts[:, 1] > lo[1]) & (pts[:, 1] < hi[1])])


def sh(args, **kw):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} exited {p.returncode}\n{p.stdout}\n{p.stderr}")
    return p


def cached(path, site=None):
    """True when path exists and is newer than what made it: the simdrive, can and
    log-merge binaries and the site's files (a drive cached before the site changed, e.g.
    gained relief, would be scored against the new map)."""
    path = pathlib.Path(path)
    if not path.exists():
        return False
    site = pathlib.Path(site) if site else ROOT / "maps" / "default"
    inputs = [BIN / "simdrive", BIN / "can", BIN / "log-merge"] + [site / f for f in ("site.yaml", "route.yaml", "world.yaml")]
    return all(path.stat().st_mtime >= i.stat().st_mtime for i in inputs if i.exists())


def make_drive(out_dir, seed, profile, duration, extra=(), site=None):
    """simdrive drive + VEHICLE_SPEED merged in: returns the path of the merged log (cached
    while newer than its inputs). extra: more simdrive options (e.g. --reverse 50); site:
    a site other than the default (passed to simdrive)."""
    out_dir = pathlib.Path(out_dir)
    merged = out_dir / "input.lcm"
    if cached(merged, site):
        return merged
    sh([BIN / "simdrive", "--out", out_dir, "--seed", seed, "--speed-profile", profile, "--duration", duration, "--quiet",
        *(["--site", site] if site else []), *extra])
    sh([BIN / "can", "--replay", out_dir / "drive.lcm", "--out", out_dir / "speed.lcm"])
    sh([BIN / "log-merge", "--quiet", "--out", merged, out_dir / "drive.lcm", out_dir / "speed.lcm"])
    return merged


def add_speed_without_gear(drive, out, work):
    """The drive with VEHICLE_SPEED decoded after dropping GEAR_PACKET (0x3BC): a car whose
    DBC has no gear, whose speeds are magnitudes. Returns out."""
    from portobello import can_frame_t
    raw = pathlib.Path(work) / "drive_nogear.lcm"
    w = lcm.EventLog(str(raw), "w", overwrite=True)
    for ev in lcm.EventLog(str(drive), "r"):
        if not (ev.channel == "CAN_FRAME" and can_frame_t.decode(ev.data).id == 0x3BC):
            w.write_event(ev.timestamp, ev.channel, ev.data)
    w.close()
    sh([BIN / "can", "--replay", raw, "--out", pathlib.Path(work) / "speed_nogear.lcm"])
    sh([BIN / "log-merge", "--quiet", "--out", out, raw, pathlib.Path(work) / "speed_nogear.lcm"])
    return out


def forward_speed(drive):
    """(GROUND_TRUTH rows as read_poses, their speed along the car's heading)."""
    gt = read_poses(drive, "GROUND_TRUTH")
    vel = np.array([pose_t.decode(e[2]).velocity[:2] for e in read_events(drive, ["GROUND_TRUTH"])])
    return gt, vel[:, 0] * np.cos(gt[:, 4]) + vel[:, 1] * np.sin(gt[:, 4])


def run_localizer(inp, out, extra=(), stats=None, timeout=1800):
    args = [BIN / "localizer", "--replay", inp, "--out", out]
    if stats:
        args += ["--stats", stats]
    args += list(extra)
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=timeout)


def read_poses(path, channel):
    """(utime, x, y, z, yaw, status) rows of a pose channel, log order."""
    rows = []
    for ev in lcm.EventLog(str(path), "r"):
        if ev.channel == channel:
            p = pose_t.decode(ev.data)
            w, x, y, z = p.orientation
            yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            rows.append((p.utime, p.position[0], p.position[1], p.position[2], yaw, p.status))
    return np.array(rows, dtype=float).reshape(-1, 6)


def read_channel_times(path, channel):
    return np.array([ev.timestamp for ev in lcm.EventLog(str(path), "r") if ev.channel == channel], dtype=float)


def read_events(path, channels):
    return [(ev.timestamp, ev.channel, ev.data) for ev in lcm.EventLog(str(path), "r") if ev.channel in channels]


def errors_vs_truth(poses, gt):
    """Translation (3-D, m) and |yaw| (deg) errors of poses against GROUND_TRUTH interpolated at their utime."""
    t = gt[:, 0]
    ok = (poses[:, 0] >= t[0]) & (poses[:, 0] <= t[-1])
    p = poses[ok]
    gx = np.interp(p[:, 0], t, gt[:, 1])
    gy = np.interp(p[:, 0], t, gt[:, 2])
    gz = np.interp(p[:, 0], t, gt[:, 3])
    gyaw = np.interp(p[:, 0], t, np.unwrap(gt[:, 4]))
    et = np.sqrt((p[:, 1] - gx) ** 2 + (p[:, 2] - gy) ** 2 + (p[:, 3] - gz) ** 2)
    ey = np.abs((p[:, 4] - gyaw + np.pi) % (2 * np.pi) - np.pi) * 180 / np.pi
    return p, et, ey


def sigmas_off(path, gt, status=1):
    """(horizontal error m, the same in standard deviations of the POSE's own x-y covariance:
    the Mahalanobis distance) of each POSE of path with this status, within the truth's span.
    What a pose claims against what it is: an honest covariance has about 1 % beyond 3 sd
    (2 degrees of freedom)."""
    t = gt[:, 0]
    e, z = [], []
    for ev in lcm.EventLog(str(path), "r"):
        if ev.channel != "POSE":
            continue
        q = pose_t.decode(ev.data)
        if q.status != status or not t[0] <= q.utime <= t[-1]:
            continue
        d = np.array([q.position[0] - np.interp(q.utime, t, gt[:, 1]), q.position[1] - np.interp(q.utime, t, gt[:, 2])])
        C = np.array(q.covariance).reshape(6, 6)[:2, :2]
        e.append(float(np.hypot(*d)))
        z.append(float(np.sqrt(d @ np.linalg.solve(C, d))) if np.all(np.isfinite(C)) and np.linalg.det(C) > 0 else np.inf)
    return np.array(e), np.array(z)


def read_stats(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def score_run(drive_log, out_log, stats_path=None):
    """Accuracy of POSE while tracking, time to tracking, LOST count, latency, POSE_PREDICTED rate."""
    gt = read_poses(drive_log, "GROUND_TRUTH")
    poses = read_poses(out_log, "POSE")
    pred = read_poses(out_log, "POSE_PREDICTED")
    r = {"poses": len(poses)}
    if len(poses) == 0:
        return r
    tracking = np.nonzero(poses[:, 5] == 1)[0]
    r["first_tracking_s"] = (poses[tracking[0], 0] - poses[0, 0]) * 1e-6 if len(tracking) else float("nan")
    after = poses[tracking[0]:] if len(tracking) else poses[:0]
    r["lost_after_tracking"] = int(np.sum(after[:, 5] == 3))
    r["not_tracking_after"] = int(np.sum(after[:, 5] != 1))
    p, et, ey = errors_vs_truth(poses[poses[:, 5] == 1], gt)
    if len(et):
        r["t_median"] = float(np.median(et))
        r["t_p99"] = float(np.percentile(et, 99))
        r["t_max"] = float(np.max(et))
        r["yaw_p99"] = float(np.percentile(ey, 99))
        _, z = sigmas_off(out_log, gt)
        r["beyond_3sd_pct"] = 100.0 * float(np.mean(z > 3)) if len(z) else float("nan")
    if len(pred) > 1:
        span = (pred[-1, 0] - pred[0, 0]) * 1e-6
        r["pred_rate_hz"] = (len(pred) - 1) / span if span > 0 else float("nan")
        _, ept, _ = errors_vs_truth(pred[pred[:, 5] == 1], gt)
        if len(ept):
            r["pred_t_p99"] = float(np.percentile(ept, 99))
    if stats_path and os.path.exists(stats_path):
        st = read_stats(stats_path)
        lat = np.array([float(s["wall_ms"]) for s in st if s["status"] == "1"])
        if len(lat):
            r["lat_p50"] = float(np.percentile(lat, 50))
            r["lat_p99"] = float(np.percentile(lat, 99))
    return r


class Listener:
    """Handles a live bus on a thread: for each channel, a function of (channel, data);
    `with Listener(url, {"POSE": fn}) as lc:` (lc publishes too), the thread stops at exit;
    or start() and close()."""

    def __init__(self, url, handlers, queue=1000):
        import threading
        self.lc = lcm.LCM(url)
        for ch, fn in handlers.items():
            self.lc.subscribe(ch, fn).set_queue_capacity(queue)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self):
        while not self.stop.is_set():
            self.lc.handle_timeout(20)

    def start(self):
        self.thread.start()
        return self.lc

    def close(self):
        self.stop.set()
        self.thread.join()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()


def lidar_poses_tum(export_dir, out):
    """The LiDAR's poses in map (TUM) from a scan-export folder: its ground_truth.tum (base
    in map) composed with base_from_lidar.txt, as import-scans --poses wants them."""
    from scipy.spatial.transform import Rotation
    export_dir = pathlib.Path(export_dir)
    base_from_lidar = np.loadtxt(export_dir / "base_from_lidar.txt").reshape(4, 4)
    gt = np.loadtxt(export_dir / "ground_truth.tum").reshape(-1, 8)
    R = Rotation.from_quat(gt[:, 4:8])   # x y z w
    pos = gt[:, 1:4] + R.apply(base_from_lidar[:3, 3])
    q = (R * Rotation.from_matrix(base_from_lidar[:3, :3])).as_quat()
    np.savetxt(out, np.column_stack([gt[:, 0], pos, q]), fmt="%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f")
