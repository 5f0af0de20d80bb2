"""tools/simdrive: the simulated site and drive.

Every drive is written to a temporary folder; drives are shared between tests by
module-scoped fixtures (one 60 s drive for rates and sensor checks, short drives
for determinism, LiDAR-free drives for the GNSS error statistics).
"""
import math
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import VEHICLE, read_log

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = ROOT / "build" / "bin" / "simdrive"
SITE = ROOT / "maps" / "default"
DBC = ROOT / "vehicles" / "dbc" / "toyota_prius_2017_pt_generated.dbc"
sys.path.insert(0, str(ROOT / "build" / "python"))

import lcm  # noqa: E402
import portobello  # noqa: E402

G = 9.80665
UTIME0 = 1714572000000000       # 2024-05-01T14:00:00Z, simdrive's fixed epoch
TYPES = {
    "LIDAR_SCAN": portobello.lidar_scan_t, "IMU": portobello.imu_t, "CAN_FRAME": portobello.can_frame_t,
    "GNSS_FIX": portobello.gnss_fix_t, "GROUND_TRUTH": portobello.pose_t,
}


def simdrive(out, *args, check=True):
    p = subprocess.run([str(BIN), "--out", str(out), "--quiet", *map(str, args)], capture_output=True, text=True)
    if check and p.returncode != 0:
        raise AssertionError(f"simdrive {args} exited {p.returncode}: {p.stderr}")
    return p


class Drive:
    """A decoded drive: messages per channel (LIDAR_SCAN kept encoded until asked)."""

    def __init__(self, folder, duration):
        self.folder = pathlib.Path(folder)
        self.duration = duration
        self.msgs = {k: [] for k in TYPES}
        self.raw_scans = []
        self.event_times = {k: [] for k in TYPES}
        self.log_order = []         # every event's timestamp, in log order
        for ev in lcm.EventLog(str(self.folder / "drive.lcm"), "r"):
            self.event_times[ev.channel].append(ev.timestamp)
            self.log_order.append(ev.timestamp)
            if ev.channel == "LIDAR_SCAN":
                self.raw_scans.append(ev.data)
            else:
                self.msgs[ev.channel].append(TYPES[ev.channel].decode(ev.data))
        gt = self.msgs["GROUND_TRUTH"]
        self.gt_t = np.array([m.utime for m in gt], dtype=np.int64)
        self.gt_pos = np.array([m.position for m in gt])
        self.gt_vel = np.array([m.velocity for m in gt])
        self.gt_w = np.array([m.angular_velocity for m in gt])
        q = np.array([m.orientation for m in gt])
        self.gt_q = q
        # ZYX angles (the car pitches and rolls: body motion, and terrain on sites that have it)
        w, x, y, z = q.T
        self.gt_roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        self.gt_pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
        self.gt_yaw = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
        self.gt_speed = np.hypot(self.gt_vel[:, 0], self.gt_vel[:, 1])

    def scan(self, i):
        return portobello.lidar_scan_t.decode(self.raw_scans[i])

    def interp(self, utime, values):
        """GROUND_TRUTH quantity linearly interpolated at utime (us)."""
        return np.interp(np.asarray(utime, dtype=np.float64), self.gt_t.astype(np.float64), values)

    def can(self, can_id):
        return [m for m in self.msgs["CAN_FRAME"] if m.id == can_id]


@pytest.fixture(scope="module")
def drive60(tmp):
    simdrive(tmp / "d60", "--seed", 7, "--duration", 60)
    return Drive(tmp / "d60", 60.0)


@pytest.fixture(scope="module")
def short_drives(tmp):
    """Seed 1 twice, seed 2 once: 12 s each (aggressive, so the car is moving early)."""
    out = {}
    for name, seed in (("a", 1), ("a2", 1), ("b", 2)):
        simdrive(tmp / name, "--seed", seed, "--duration", 12, "--speed-profile", "aggressive")
        out[name] = Drive(tmp / name, 12.0)
    return out


# ---------------------------------------------------------------- helpers

def scan_xyz(scan):
    """The range-image model of lidar_scan_t.lcm: xyz (lidar frame), valid mask, column of each pixel."""
    rows, cols = scan.rows, scan.cols
    rng = np.array(scan.range_mm, dtype=np.float64).reshape(rows, cols) / 1000.0
    c = np.arange(cols)
    enc = 2 * np.pi * (1 - c / cols)
    alt = np.array(scan.beam_altitude_rad)[:, None]
    th = enc[None, :] + np.array(scan.beam_azimuth_rad)[:, None]
    n = scan.beam_origin_m
    rn = rng - n
    x = rn * np.cos(th) * np.cos(alt) + n * np.cos(enc)[None, :]
    y = rn * np.sin(th) * np.cos(alt) + n * np.sin(enc)[None, :]
    z = rn * np.sin(alt) + 0 * enc[None, :]
    M = np.array(scan.lidar_from_beam).reshape(4, 4)
    p = np.stack([x, y, z], axis=-1) @ M[:3, :3].T + M[:3, 3]
    cols_idx = np.broadcast_to(c[None, :], (rows, cols))
    return p, rng > 0, cols_idx


def rpy_matrix(rpy_deg):
    r, p, y = np.radians(rpy_deg)
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def zyx_matrices(roll, pitch, yaw):
    """Rotation matrices Rz(yaw) Ry(pitch) Rx(roll), one per element (n x 3 x 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
                     np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], -2)


def scan_to_map(drive, scan, vehicle, per_column_time=True):
    """Points of a scan in map, each moved by the GT pose at its column's time
    (or, per_column_time=False, all by the pose at the sweep start)."""
    p, valid, cidx = scan_xyz(scan)
    lid = vehicle["sensors"]["lidar"]
    Rl, tl = rpy_matrix(lid.get("rpy_deg", [0, 0, 0])), np.array(lid["xyz"])
    pb = p[valid] @ Rl.T + tl
    offs = np.array(scan.col_offset_us)[cidx[valid]] if per_column_time else np.zeros(valid.sum())
    t = scan.utime + offs
    pos = np.stack([drive.interp(t, drive.gt_pos[:, k]) for k in range(3)], axis=-1)
    R = zyx_matrices(drive.interp(t, drive.gt_roll), drive.interp(t, drive.gt_pitch), drive.interp(t, drive.gt_yaw))
    out = pos + np.einsum("nij,nj->ni", R, pb)
    rows = np.broadcast_to(np.arange(scan.rows)[:, None], (scan.rows, scan.cols))[valid]
    return out, rows


@pytest.fixture(scope="module")
def ground(tmp):
    """The default site's true ground (its terrain), as heights at points: simdrive
    --terrain-out gives the road and sidewalk band; beyond it the simulator keeps the
    sidewalk's outer height, so the nearest band cell's height is the ground there."""
    from scipy import ndimage
    run_out = tmp / "truth.yaml"
    subprocess.run([str(BIN), "--site", str(SITE), "--terrain-out", str(run_out)], check=True, capture_output=True)
    import importlib.util
    spec = importlib.util.spec_from_file_location("bench_terrain", ROOT / "tools" / "bench-terrain" / "bench.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    x0, y0, c, z = mod.read_ground(run_out)
    idx = ndimage.distance_transform_edt(np.isnan(z), return_distances=False, return_indices=True)
    z = z[tuple(idx)]
    return lambda x, y: mod.sample((x0, y0, c, z), np.asarray(x, dtype=float), np.asarray(y, dtype=float))


def world_primitives(ground, day="drive"):
    """Static primitives as simdrive stands them on the terrain (tools/simdrive/world.c):
    a box or cylinder reaches down to the lowest ground under its footprint (z0 = 0) and
    up to its height above the ground at its centre; a sphere rises with the ground."""
    w = yaml.safe_load((SITE / "world.yaml").read_text())
    boxes, cyls, sphs = [], [], []
    for o in w["objects"]:
        if o.get("day", "both") not in ("both", day):
            continue
        cx, cy = o["center"][:2]
        hc = float(ground(cx, cy))
        if o["type"] == "box":
            yaw = math.radians(o.get("yaw_deg", 0))
            hx, hy = o["size"][0] / 2, o["size"][1] / 2
            u, v = np.array([1, -1, 1, -1]) * hx, np.array([1, 1, -1, -1]) * hy
            lo = min(hc, ground(cx + np.cos(yaw) * u - np.sin(yaw) * v, cy + np.sin(yaw) * u + np.cos(yaw) * v).min())
            z0 = o.get("z0", 0)
            boxes.append([cx, cy, yaw, hx, hy, lo if z0 == 0 else z0 + hc, hc + z0 + o["size"][2]])
        elif o["type"] == "cylinder":
            r = o["radius"]
            lo = min(hc, ground(cx + np.array([r, -r, r, -r]), cy + np.array([r, r, -r, -r])).min())
            z0 = o.get("z0", 0)
            cyls.append([cx, cy, r, lo if z0 == 0 else z0 + hc, hc + z0 + o["height"]])
        else:
            sphs.append([cx, cy, o["center"][2] + hc, o["radius"]])
    return np.array(boxes), np.array(cyls), np.array(sphs)


def distance_to_world(pts, prims, near_xy, radius=45.0):
    """Unsigned distance of each point to the nearest static primitive (not the ground)."""
    boxes, cyls, sphs = prims
    best = np.full(len(pts), np.inf)
    b = boxes[np.hypot(boxes[:, 0] - near_xy[0], boxes[:, 1] - near_xy[1]) < radius + 30]
    for cx, cy, yaw, hx, hy, z0, z1 in b:
        dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
        lx, ly = dx * np.cos(yaw) + dy * np.sin(yaw), -dx * np.sin(yaw) + dy * np.cos(yaw)
        hz, cz = (z1 - z0) / 2, (z0 + z1) / 2
        q = np.stack([np.abs(lx) - hx, np.abs(ly) - hy, np.abs(pts[:, 2] - cz) - hz], axis=-1)
        d = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
        best = np.minimum(best, np.abs(d))
    c = cyls[np.hypot(cyls[:, 0] - near_xy[0], cyls[:, 1] - near_xy[1]) < radius]
    for cx, cy, r, z0, z1 in c:
        dr = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
        dz = np.abs(pts[:, 2] - (z0 + z1) / 2) - (z1 - z0) / 2
        d = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)) + np.minimum(np.maximum(dr, dz), 0)
        best = np.minimum(best, np.abs(d))
    s = sphs[np.hypot(sphs[:, 0] - near_xy[0], sphs[:, 1] - near_xy[1]) < radius]
    for cx, cy, cz, r in s:
        d = np.sqrt((pts[:, 0] - cx) ** 2 + (pts[:, 1] - cy) ** 2 + (pts[:, 2] - cz) ** 2) - r
        best = np.minimum(best, np.abs(d))
    return best


def wgs84_to_map(lat, lon, alt, geo):
    """Geodetic -> ECEF -> ENU at the site origin -> map (rotated by yaw_deg)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)

    def ecef(la, lo, h):
        la, lo = np.radians(la), np.radians(lo)
        N = a / np.sqrt(1 - e2 * np.sin(la) ** 2)
        return np.stack([(N + h) * np.cos(la) * np.cos(lo), (N + h) * np.cos(la) * np.sin(lo),
                         (N * (1 - e2) + h) * np.sin(la)], axis=-1)
    p0 = ecef(geo["lat0_deg"], geo["lon0_deg"], geo["alt0_m"])
    d = ecef(np.asarray(lat), np.asarray(lon), np.asarray(alt)) - p0
    la0, lo0 = math.radians(geo["lat0_deg"]), math.radians(geo["lon0_deg"])
    e = -math.sin(lo0) * d[:, 0] + math.cos(lo0) * d[:, 1]
    n = (-math.sin(la0) * math.cos(lo0) * d[:, 0] - math.sin(la0) * math.sin(lo0) * d[:, 1]
         + math.cos(la0) * d[:, 2])
    u = math.cos(la0) * math.cos(lo0) * d[:, 0] + math.cos(la0) * math.sin(lo0) * d[:, 1] + math.sin(la0) * d[:, 2]
    yaw = math.radians(geo.get("yaw_deg", 0))
    return np.stack([math.cos(yaw) * e + math.sin(yaw) * n, -math.sin(yaw) * e + math.cos(yaw) * n, u], axis=-1)


# ---------------------------------------------------------------- (0) CLI

def test_help():
    p = subprocess.run([str(BIN), "--help"], capture_output=True, text=True)
    assert p.returncode == 0 and "--speed-profile" in p.stdout and "--mapping" in p.stdout


# ---------------------------------------------------------------- (1) determinism

def _fields(drive):
    out = []
    for ch in ("IMU", "CAN_FRAME", "GNSS_FIX", "GROUND_TRUTH"):
        for m in drive.msgs[ch]:
            out.append((ch, m.utime, tuple(getattr(m, "accel", ())), tuple(getattr(m, "gyro", ())),
                        bytes(getattr(m, "data", b"")), getattr(m, "lat_deg", 0.0), getattr(m, "lon_deg", 0.0),
                        tuple(getattr(m, "position", ())), tuple(getattr(m, "velocity", ()))))
    return out


def test_same_seed_same_content(short_drives):
    a, a2 = short_drives["a"], short_drives["a2"]
    assert _fields(a) == _fields(a2)
    assert len(a.raw_scans) == len(a2.raw_scans) == 120
    for i in (0, 57, 119):
        s1, s2 = a.scan(i), a2.scan(i)
        assert s1.utime == s2.utime and s1.seq == s2.seq
        assert s1.range_mm == s2.range_mm and s1.reflectivity == s2.reflectivity


def test_lidar_from_gives_the_whole_drives_sweeps_from_then_on(short_drives, tmp_path):
    """--lidar-from 9.05: no sweep before 9.05 s; the sweeps from then on and every other
    message are the whole drive's, byte for byte (a sweep's noise is drawn from its index)."""
    simdrive(tmp_path, "--seed", 1, "--duration", 12, "--speed-profile", "aggressive", "--lidar-from", 9.05)
    whole = list(read_log(short_drives["a"].folder / "drive.lcm"))
    late = list(read_log(tmp_path / "drive.lcm"))
    t0 = whole[0][1]
    assert late[0][1] == t0
    first = next(t for ch, t, _ in whole if ch == "LIDAR_SCAN" and t - t0 >= 9.05e6)
    assert [e for e in whole if e[0] != "LIDAR_SCAN" or e[1] >= first] == late
    assert sum(ch == "LIDAR_SCAN" for ch, _, _ in late) == 29      # sweeps 91-119 of 120


def test_different_seed_differs(short_drives):
    a, b = short_drives["a"], short_drives["b"]
    ga = np.array([m.gyro for m in a.msgs["IMU"]])
    gb = np.array([m.gyro for m in b.msgs["IMU"]])
    assert not np.allclose(ga, gb)
    la = np.array([m.lat_deg for m in a.msgs["GNSS_FIX"]])
    lb = np.array([m.lat_deg for m in b.msgs["GNSS_FIX"]])
    assert np.abs(la - lb).max() > 1e-6
    ra, rb = np.array(a.scan(60).range_mm), np.array(b.scan(60).range_mm)
    assert (ra != rb).mean() > 0.5     # noise differs on most pixels


# ---------------------------------------------------------------- (2) rates

def test_channel_rates(drive60):
    d, T = drive60, drive60.duration
    n = {k: len(v) for k, v in d.msgs.items()}
    n["LIDAR_SCAN"] = len(d.raw_scans)
    assert n["LIDAR_SCAN"] / T == pytest.approx(10.0, rel=0.01)
    assert n["IMU"] / T >= 100 and n["IMU"] / T == pytest.approx(200.0, rel=0.01)
    assert len(d.can(0x0AA)) / T == pytest.approx(1000 / 12, rel=0.01)
    assert len(d.can(0x0B4)) / T == pytest.approx(1000 / 24, rel=0.01)
    assert len(d.can(0x3BC)) / T == pytest.approx(1.0, rel=0.05)        # GEAR_PACKET, no shift
    assert n["GNSS_FIX"] / T == pytest.approx(10.0, rel=0.01)
    assert n["GROUND_TRUTH"] / T == pytest.approx(100.0, rel=0.01)
    # log event time = message utime, in order, from the fixed epoch
    for ch, msgs in d.msgs.items():
        if ch != "LIDAR_SCAN":
            assert [m.utime for m in msgs] == d.event_times[ch]
    assert [d.scan(i).utime for i in (0, 1, 599)] == [d.event_times["LIDAR_SCAN"][i] for i in (0, 1, 599)]
    assert d.log_order == sorted(d.log_order)
    assert d.log_order[0] >= UTIME0 and d.log_order[-1] < UTIME0 + T * 1e6
    # the car actually drives: it covers ground and stops at stop lines
    dist = np.sum(np.hypot(*np.diff(d.gt_pos[:, :2], axis=0).T))
    assert 250 < dist < 700
    moving = d.gt_speed > 0.05
    assert np.sum(np.diff(moving.astype(int)) == -1) >= 2       # came to rest at least twice


# ---------------------------------------------------------------- (3) IMU and CAN integration vs GT

def test_gyro_and_can_integrate_to_ground_truth(drive60, vehicle):
    d, sim = drive60, vehicle["simulation"]
    imu = d.msgs["IMU"]
    t = np.array([m.utime for m in imu], dtype=np.float64)
    gz = np.array([m.gyro[2] for m in imu])
    dt = np.diff(t) * 1e-6
    T = (t[-1] - t[0]) * 1e-6
    # Yaw: the integrated gyro differs from GT by bias * T plus the random walk of the
    # white noise, sigma_g * dt * sqrt(N). The bias is N(0, gyro_bias) per drive, so a
    # 4-sigma bound is 4 * gyro_bias * T; add 4 sigma of the random walk and 1e-3 rad for
    # trapezoid integration of a smooth rate at 200 Hz.
    yaw_imu = np.sum(0.5 * (gz[1:] + gz[:-1]) * dt)
    yaw_gt = d.interp(t[-1], d.gt_yaw) - d.interp(t[0], d.gt_yaw)
    bound = 4 * sim["gyro_bias"] * T + 4 * sim["gyro_noise"] * np.mean(dt) * math.sqrt(len(gz)) + 1e-3
    assert abs(yaw_imu - yaw_gt) < bound, (yaw_imu, yaw_gt, bound)
    assert abs(yaw_gt) > 0.3        # the drive turns, so this says something
    # Residual against the interpolated GT rate: its mean is the bias, its spread the noise.
    res = gz - d.interp(t, d.gt_w[:, 2])
    assert abs(res.mean()) < 4 * sim["gyro_bias"]
    assert np.std(res) == pytest.approx(sim["gyro_noise"], rel=0.1)

    # Distance: SPEED is the exact GT speed quantised to 0.01 km/h (error <= 0.005 km/h =
    # 1.4 mm/s), so integrating it (trapezoid at 24 ms on a smooth speed, < 2 cm) must
    # match the GT path length within 1.4 mm/s * T + 0.05 m.
    import cantools
    db = cantools.database.load_file(str(DBC))
    spd = d.can(0x0B4)
    ts = np.array([m.utime for m in spd], dtype=np.float64)
    v = np.array([db.decode_message(0x0B4, bytes(m.data))["SPEED"] for m in spd]) / 3.6
    dist_can = np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(ts) * 1e-6)
    sel = (d.gt_t >= ts[0]) & (d.gt_t <= ts[-1])
    p = d.gt_pos[sel, :2]
    dist_gt = np.sum(np.hypot(*np.diff(p, axis=0).T))
    # GT samples nearest the first / last frame are up to 10 ms inside: add that travel
    dist_gt += d.interp(ts[0], d.gt_speed) * (d.gt_t[sel][0] - ts[0]) * 1e-6
    dist_gt += d.interp(ts[-1], d.gt_speed) * (ts[-1] - d.gt_t[sel][-1]) * 1e-6
    assert abs(dist_can - dist_gt) < 0.005 / 3.6 * T + 0.05, (dist_can, dist_gt)


def ideal_specific_force(d, t, vehicle):
    """What an ideal IMU at its lever arm measures (imu frame = base here), from GT alone:
    R^T (a + g_up) + alpha x r + w x (w x r), with the GT's full 3-D orientation, velocity
    (central differences: the motion is smooth, the error is far below 1e-3 m/s^2) and
    body rates. NaN outside the GT's span."""
    tg = d.gt_t.astype(np.float64) * 1e-6
    a_map = np.gradient(d.gt_vel, tg, axis=0)
    alpha = np.gradient(d.gt_w, tg, axis=0)
    ai = np.stack([d.interp(t, a_map[:, k]) for k in range(3)], -1)
    w = np.stack([d.interp(t, d.gt_w[:, k]) for k in range(3)], -1)
    al = np.stack([d.interp(t, alpha[:, k]) for k in range(3)], -1)
    R = zyx_matrices(d.interp(t, d.gt_roll), d.interp(t, d.gt_pitch), d.interp(t, d.gt_yaw))
    a_base = np.einsum("nji,nj->ni", R, ai + np.array([0, 0, G]))
    r = np.array(vehicle["sensors"]["imu"]["xyz"], dtype=float)
    f = a_base + np.cross(al, r) + np.cross(w, np.cross(w, r))
    f[(t <= d.gt_t[1]) | (t >= d.gt_t[-2])] = np.nan
    return f


def test_accelerometer_matches_ground_truth(drive60, vehicle):
    d, sim = drive60, vehicle["simulation"]
    imu = d.msgs["IMU"]
    t = np.array([m.utime for m in imu], dtype=np.float64)
    acc = np.array([m.accel for m in imu])
    f = ideal_specific_force(d, t, vehicle)
    ok = ~np.isnan(f[:, 0])
    res = acc[ok] - f[ok]
    # per axis: mean = the drive's bias (N(0, accel_bias): 4-sigma bound), spread = noise
    assert np.all(np.abs(res.mean(axis=0)) < 4 * sim["accel_bias"]), res.mean(axis=0)
    assert np.all(np.abs(res.std(axis=0) / sim["accel_noise"] - 1) < 0.15), res.std(axis=0)
    assert np.ptp(f[ok, 0]) > 1.0 and np.ptp(f[ok, 1]) > 0.5   # the drive accelerates and turns


# ---------------------------------------------------------------- (4) CAN through the DBC

def test_can_frames_decode_to_ground_truth(drive60, vehicle):
    import cantools
    db = cantools.database.load_file(str(DBC))
    d = drive60
    dims = vehicle["dimensions"]
    L, hf, hr = dims["wheelbase"], dims["track_front"] / 2, dims["track_rear"] / 2
    # the wheels roll the 3-D path (on a grade longer than its map projection)
    v, w = np.linalg.norm(d.gt_vel, axis=1), d.gt_w[:, 2]
    # wheel contact points move with v + w x r: rear (0, +-hr), front (L, +-hf)
    wheel_gt = {
        "WHEEL_SPEED_FL": np.hypot(v - w * hf, w * L), "WHEEL_SPEED_FR": np.hypot(v + w * hf, w * L),
        "WHEEL_SPEED_RL": np.abs(v - w * hr), "WHEEL_SPEED_RR": np.abs(v + w * hr),
    }
    frames = d.msgs["CAN_FRAME"]
    assert frames and all(m.bus == 0 and m.len == 8 and not m.extended for m in frames)
    worst = 0.0
    for m in frames:
        if m.utime > d.gt_t[-1]:
            continue        # after the last GT sample: nothing to interpolate
        data = bytes(m.data)
        sig = db.decode_message(m.id, data)
        if m.id == 0x0AA:
            for name, gt in wheel_gt.items():
                worst = max(worst, abs(sig[name] - 3.6 * d.interp(m.utime, gt)))
        elif m.id == 0x0B4:
            worst = max(worst, abs(sig["SPEED"] - 3.6 * d.interp(m.utime, v)))
            # Toyota checksum: id high + id low + length + data bytes 0..6
            assert sig["CHECKSUM"] == (0x00 + 0xB4 + 8 + sum(data[:7])) & 0xFF
        elif m.id == 0x3BC:
            assert str(sig["GEAR"]) == "D" and str(sig["DRIVE_ENGAGED"]) == "on"     # this drive never reverses
        else:
            pytest.fail(f"unexpected CAN id {m.id:#x}")
    assert worst <= 0.01, worst
    # the checksum rule itself, on the real frame 0B4#000000001D0B7A5E
    real = bytes.fromhex("000000001D0B7A5E")
    assert (0xB4 + 8 + sum(real[:7])) & 0xFF == real[7]
    # ENCODER counts wheel rotations: it never runs backwards, a little per frame
    enc = np.array([db.decode_message(0x0B4, bytes(m.data))["ENCODER"] for m in d.can(0x0B4)])
    steps = np.diff(enc) % 256
    assert steps.max() <= 2 and steps.sum() > 50


# ---------------------------------------------------------------- (5) LiDAR geometry and timing

def _moving_scans(d, vmin=6.0, count=6):
    idx = [i for i, ut in enumerate(d.event_times["LIDAR_SCAN"]) if d.interp(ut, d.gt_speed) > vmin]
    assert len(idx) >= count, "the drive must move fast enough"
    return idx[:: max(1, len(idx) // count)][:count]


def test_lidar_ground_points_on_the_ground(drive60, vehicle, ground):
    d = drive60
    route = np.array(yaml.safe_load((SITE / "route.yaml").read_text())["points"])
    for i in _moving_scans(d):
        scan = d.scan(i)
        assert scan.rows == 64 and scan.cols == 1024 and scan.npixels == 65536
        assert scan.col_offset_us[0] == 0 and 99000 < scan.col_offset_us[-1] < 100000
        pts, rows = scan_to_map(d, scan, vehicle)
        alt = np.degrees(np.array(scan.beam_altitude_rad))[rows]
        # downward beams landing within 1.2 m of the driven lane's centreline and within
        # 15 m of the car: the lane ahead and behind is empty road (on the terrain).
        car = d.interp(scan.utime, d.gt_pos[:, 0]), d.interp(scan.utime, d.gt_pos[:, 1])
        near = np.hypot(pts[:, 0] - car[0], pts[:, 1] - car[1]) < 15
        sel = pts[(alt < -5) & near]
        dl = np.min(np.hypot(sel[:, None, 0] - route[None, :, 0], sel[:, None, 1] - route[None, :, 1]), axis=1)
        sel = sel[dl < 1.2]
        z = sel[:, 2] - ground(sel[:, 0], sel[:, 1])
        assert len(z) > 200
        # noise 2 cm along the ray projects to < 1 cm in z for beams 5-17 deg down
        assert np.percentile(np.abs(z), 99) < 0.03, np.percentile(np.abs(z), 99)
        assert abs(np.median(z)) < 0.005


def test_lidar_per_column_time_matters(drive60, vehicle, ground):
    """Moving at > 6 m/s the car travels 0.6+ m during a sweep: points moved with the
    pose at their column's time land on the world's surfaces; moved with the sweep
    start's pose, they are measurably off."""
    d = drive60
    prims = world_primitives(ground, "drive")
    good, bad = [], []
    for i in _moving_scans(d):
        scan = d.scan(i)
        car = d.interp(scan.utime, d.gt_pos[:, 0]), d.interp(scan.utime, d.gt_pos[:, 1])
        for per_col, acc in ((True, good), (False, bad)):
            pts, _ = scan_to_map(d, scan, vehicle, per_column_time=per_col)
            # above the kerbs (not ground) and within 40 m: buildings, trees, poles, cars
            keep = ((pts[:, 2] - ground(pts[:, 0], pts[:, 1]) > 0.4)
                    & (np.hypot(pts[:, 0] - car[0], pts[:, 1] - car[1]) < 40))
            dist = distance_to_world(pts[keep], prims, car)
            acc.append(dist[dist < 2.0])     # farther: moving traffic, not in the static list
    good, bad = np.concatenate(good), np.concatenate(bad)
    assert len(good) > 10000
    # the noise is 2 cm: with per-column time, points sit on the surfaces
    assert np.median(good) < 0.02, np.median(good)
    assert np.mean(good < 0.08) > 0.95, np.mean(good < 0.08)
    # ignoring the column time is clearly worse
    assert np.mean(bad) > 3 * np.mean(good), (np.mean(bad), np.mean(good))
    assert np.mean(bad < 0.08) < np.mean(good < 0.08) - 0.1


def test_lidar_returns_and_reflectivity(drive60):
    scan = drive60.scan(300)
    r = np.array(scan.range_mm).reshape(64, 1024)
    refl = np.array(bytearray(scan.reflectivity)).reshape(64, 1024)
    # the sky: upward beams miss often; downward beams mostly return
    assert (r[:8] == 0).mean() > 0.2
    assert (r[40:] > 0).mean() > 0.9
    assert np.all((refl > 0) == (r > 0))
    assert len(np.unique(refl[r > 0] // 10)) >= 3      # several materials
    assert r.max() <= 120000 + 200


# ---------------------------------------------------------------- (6) size

def test_porous_foliage(tmp):
    """--foliage-depth: a beam into a canopy stops inside it, at an exponential depth, or
    goes through. Same seed, so the noise of every pixel is the same as the solid run's:
    only beams that hit foliage change, and only to farther."""
    ranges = {}
    for name, extra in (("solid", ()), ("porous", ("--foliage-depth", 0.7)), ("porous2", ("--foliage-depth", 0.7))):
        simdrive(tmp / f"fol_{name}", "--seed", 3, "--duration", 1, *extra)
        scans = [Drive.scan(d, i) for d in [Drive(tmp / f"fol_{name}", 1.0)] for i in range(len(d.raw_scans))]
        ranges[name] = (np.array([s.range_mm for s in scans], dtype=np.float64),
                        np.array([list(s.reflectivity) for s in scans]))
    (rs, fs), (rp, fp), (rp2, _) = ranges["solid"], ranges["porous"], ranges["porous2"]
    assert np.array_equal(rp, rp2)                                  # deterministic
    both, changed = (rs > 0) & (rp > 0), rs != rp
    assert np.min(rp[both] - rs[both]) >= 0                        # never nearer
    folband = (fs >= 42) & (fs <= 48)                               # foliage: albedo 0.45 +- 5 %
    assert changed.sum() > 10000 and np.all(folband[changed]), changed.sum()   # measured 61,376 of 655,360
    inside = both & changed & (fp >= 42) & (fp <= 48) & (rp - rs < 6000)
    depth = np.median(rp[inside] - rs[inside]) / 1000
    # exponential of mean 0.7 m: median 0.49 m, less where the canopy is thinner; measured 0.449
    assert 0.35 < depth < 0.49, depth
    assert np.sum((rs > 0) & (rp == 0)) > 100                      # some go through into the sky (measured 1,120)


def test_scan_encoded_size(drive60):
    sizes = [len(s) for s in drive60.raw_scans]
    assert max(sizes) <= 600 * 1024
    assert min(sizes) > 300 * 1024      # 64 x 1024 x (4 + 1) bytes plus the beam tables


# ---------------------------------------------------------------- (7) GNSS

@pytest.fixture(scope="module")
def gnss_drives(tmp):
    """LiDAR-free 300 s drives with four seeds: 60 correlation times of GNSS error."""
    out = []
    for seed in (11, 12, 13, 14):
        simdrive(tmp / f"g{seed}", "--seed", seed, "--duration", 300, "--no-lidar")
        out.append(Drive(tmp / f"g{seed}", 300.0))
    return out


def test_gnss_error_distribution(gnss_drives, vehicle):
    geo = yaml.safe_load((SITE / "site.yaml").read_text())["georef"]
    ant = vehicle["sensors"]["gnss"]["xyz"]
    errs, haccs = [], []
    for d in gnss_drives:
        fixes = d.msgs["GNSS_FIX"]
        assert all(f.fix_type == portobello.gnss_fix_t.FIX_3D for f in fixes)
        t = np.array([f.utime for f in fixes], dtype=np.float64)
        p = wgs84_to_map([f.lat_deg for f in fixes], [f.lon_deg for f in fixes], [f.alt_m for f in fixes], geo)
        yaw = d.interp(t, d.gt_yaw)
        tx = d.interp(t, d.gt_pos[:, 0]) + np.cos(yaw) * ant[0] - np.sin(yaw) * ant[1]
        ty = d.interp(t, d.gt_pos[:, 1]) + np.sin(yaw) * ant[0] + np.cos(yaw) * ant[1]
        errs.append(np.hypot(p[:, 0] - tx, p[:, 1] - ty))
        haccs += [f.h_acc_m for f in fixes]
        # reported speed is the GT speed within its 5 cm/s noise
        spd = np.array([f.speed_mps for f in fixes])
        assert np.abs(spd - d.interp(t, d.gt_speed)).max() < 0.3
    e = np.concatenate(errs)
    # gnss_noise is the 1-sigma error per horizontal axis, so |e| is Rayleigh(1.5 m):
    # median 1.77 m, 67 % within 1-3 m, 1 % beyond 4.5 m.
    assert 1.0 < np.median(e) < 2.6, np.median(e)
    assert np.mean((e > 1) & (e < 3)) > 0.45
    assert np.percentile(e, 99) < 6.0
    assert np.median(haccs) == pytest.approx(vehicle["simulation"]["gnss_noise"] * np.sqrt(2))
    # and it is honest: the reported horizontal RMS matches the measured one within 20 %
    assert np.sqrt(np.mean(e ** 2)) == pytest.approx(np.median(haccs), rel=0.2)


# ---------------------------------------------------------------- (8) TUM file

def test_tum_matches_ground_truth(drive60):
    d = drive60
    tum = np.loadtxt(d.folder / "ground_truth.tum")
    assert tum.shape == (len(d.msgs["GROUND_TRUTH"]), 8)
    assert np.allclose(tum[:, 0], d.gt_t * 1e-6, atol=1e-6, rtol=0)
    assert np.allclose(tum[:, 1:4], d.gt_pos, atol=1e-6)
    q = np.array([m.orientation for m in d.msgs["GROUND_TRUTH"]])
    assert np.allclose(tum[:, 4:8], q[:, [1, 2, 3, 0]], atol=1e-8)    # qx qy qz qw
    m0 = d.msgs["GROUND_TRUTH"][0]
    assert m0.source == portobello.pose_t.SOURCE_GROUND_TRUTH and m0.status == portobello.pose_t.STATUS_TRACKING


# ---------------------------------------------------------------- (9) bad input

def test_bad_site_and_vehicle_files(tmp):
    out = tmp / "bad-out"
    p = simdrive(out, "--site", tmp / "no-such-site", check=False)
    assert p.returncode != 0 and "no-such-site" in p.stderr

    site = tmp / "bad-site"
    shutil.copytree(SITE, site, ignore=shutil.ignore_patterns("*.pcd", ".gitignore"))
    route = (site / "route.yaml").read_text().splitlines()
    line = next(i for i, s in enumerate(route) if s.startswith("lane_width")) + 1
    route[line - 1] = "lane_widht: 3.5"
    (site / "route.yaml").write_text("\n".join(route) + "\n")
    p = simdrive(out, "--site", site, "--duration", 1, check=False)
    assert p.returncode != 0
    assert f"route.yaml:{line}:" in p.stderr and "lane_widht" in p.stderr

    world = (site / "world.yaml")
    shutil.copy(SITE / "route.yaml", site / "route.yaml")
    wl = world.read_text().splitlines()
    k = next(i for i, s in enumerate(wl) if "type: cylinder" in s)
    wl[k] = wl[k].replace("radius: ", "radius: wide") if "radius: " in wl[k] else wl[k]
    world.write_text("\n".join(wl) + "\n")
    p = simdrive(out, "--site", site, "--duration", 1, check=False)
    assert p.returncode != 0 and f"world.yaml:{k + 1}:" in p.stderr and "radius" in p.stderr

    veh = tmp / "bad-vehicle.yaml"
    vl = VEHICLE.read_text().splitlines()
    k = next(i for i, s in enumerate(vl) if s.strip().startswith("wheelbase:"))
    vl[k] = "  wheelbase: long"
    veh.write_text("\n".join(vl) + "\n")
    p = simdrive(out, "--vehicle", veh, "--duration", 1, check=False)
    assert p.returncode != 0 and f"bad-vehicle.yaml:{k + 1}:" in p.stderr and "wheelbase" in p.stderr

    p = simdrive(out, "--speed-profile", "reckless", check=False)
    assert p.returncode != 0 and "reckless" in p.stderr


# ---------------------------------------------------------------- the default site's prior map

def test_default_prior_map_is_the_mapping_day(ground):
    """maps/default/map.pcd (built by make from a --mapping drive) lies on the
    mapping-day surfaces: map-only parked cars are in it, drive-only ones are not."""
    pcd = SITE / "map.pcd"
    assert pcd.exists(), "maps/default/map.pcd not built: make test builds it"
    raw = pcd.read_bytes()
    head = raw[: raw.index(b"DATA binary\n")].decode()
    assert "FIELDS x y z intensity" in head and "TYPE F F F F" in head
    pts = np.frombuffer(raw[raw.index(b"DATA binary\n") + 12:], dtype=np.float32).reshape(-1, 4)[:, :3]
    pts = pts.astype(np.float64)
    h = pts[:, 2] - ground(pts[:, 0], pts[:, 1])     # height above the terrain
    assert np.mean(np.abs(h) < 0.05) > 0.3
    above, h_above = pts[h > 0.4], h[h > 0.4]
    sample = above[np.random.default_rng(0).choice(len(above), 20000, replace=False)]
    dist = distance_to_world(sample, world_primitives(ground, "map"), (300.0, 90.0), radius=1e9)
    # 15 cm voxel centroids of 2 cm-noise points on smooth surfaces
    assert np.median(dist) < 0.03 and np.mean(dist < 0.15) > 0.97, (np.median(dist), np.mean(dist < 0.15))
    w = yaml.safe_load((SITE / "world.yaml").read_text())
    low = above[h_above < 1.8]          # car height, below tree crowns
    for day, present in (("map", True), ("drive", False)):
        cars = [o for o in w["objects"] if o.get("day") == day and o["size"][2] > 0.7]   # car bodies
        assert len(cars) >= 3
        hits = [np.sum(np.hypot(low[:, 0] - o["center"][0], low[:, 1] - o["center"][1]) < 1.0) for o in cars]
        if present:
            assert np.mean([h > 5 for h in hits]) > 0.8, hits
        else:
            assert max(hits) == 0, hits
