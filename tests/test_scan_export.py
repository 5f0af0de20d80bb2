"""tools/scan-export: a log's sweeps as float32 x y z t files (for make bench-mapper).

A short simulated drive (range-image sweeps) checks counts, times, ground truth and the
extrinsic; the HDL-32E pair imported as point sweeps checks the points themselves against
the PCD files they came from; then the errors."""
import math
import pathlib
import subprocess

import numpy as np
import pytest
import yaml

from conftest import BIN, ROOT, VEHICLE

import lcm  # noqa: E402
import portobello  # noqa: E402

EXPORT = BIN / "scan-export"
HDL = ROOT / "tests" / "data" / "lidar_pair_hdl32"


def run(args, check=True):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if check and p.returncode != 0:
        raise AssertionError(f"{args} exited {p.returncode}: {p.stderr}")
    return p


def read_bin(path):
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)


def read_pcd_xyz(path):
    """x y z of a binary PCD with fields x y z intensity (float32)."""
    with open(path, "rb") as f:
        n = 0
        for line in iter(f.readline, b""):
            if line.startswith(b"FIELDS"):
                assert line.split()[1:] == [b"x", b"y", b"z", b"intensity"], line
            if line.startswith(b"POINTS"):
                n = int(line.split()[1])
            if line.startswith(b"DATA"):
                assert b"binary" in line
                return np.frombuffer(f.read(16 * n), dtype="<f4").reshape(n, 4)[:, :3]
    raise AssertionError(f"{path}: no DATA line")


@pytest.fixture(scope="module")
def sim(tmp):
    """A 1.5 s simulated drive, exported whole and every 3rd sweep."""
    run([BIN / "simdrive", "--out", tmp / "drive", "--duration", 1.5, "--seed", 3, "--quiet"])
    log = tmp / "drive" / "drive.lcm"
    p = run([EXPORT, "--log", log, "--out", tmp / "all", "--quiet"])
    run([EXPORT, "--log", log, "--out", tmp / "every3", "--every", 3, "--quiet"])
    scans, truth = [], []
    for ev in lcm.EventLog(str(log), "r"):
        if ev.channel == "LIDAR_SCAN":
            scans.append(portobello.lidar_scan_t.decode(ev.data))
        elif ev.channel == "GROUND_TRUTH":
            truth.append(portobello.pose_t.decode(ev.data))
    return {"dir": tmp, "log": log, "scans": scans, "truth": truth, "stderr": p.stderr}


def test_sim_sweeps_match_the_range_images(sim):
    d, scans = sim["dir"] / "all", sim["scans"]
    assert len(scans) >= 10
    files = sorted((d / "scans").glob("*.bin"))
    assert [f.name for f in files] == [f"{k:06d}.bin" for k in range(len(scans))]
    times = np.loadtxt(d / "times.txt")
    assert [round(t * 1e6) for t in times] == [s.utime for s in scans]
    for k in (0, len(scans) // 2, len(scans) - 1):
        s, pts = scans[k], read_bin(files[k])
        assert s.npixels > 0 and s.npoints == 0        # simdrive sweeps are range images
        R = np.array(s.range_mm, dtype=np.int64).reshape(s.rows, s.cols)
        valid = R > 0
        assert len(pts) == valid.sum()                 # one point per return
        # each point's time is its column's, in seconds
        col_t = np.broadcast_to(np.array(s.col_offset_us, dtype=np.float64), R.shape)[valid]
        assert np.array_equal(np.sort(pts[:, 3]), np.sort((col_t * 1e-6).astype(np.float32)))
        # distances are the ranges up to the beam origin offset (lidar_from_beam is the identity here)
        assert np.allclose(s.lidar_from_beam, np.eye(4).ravel())
        dist = np.sort(np.linalg.norm(pts[:, :3].astype(np.float64), axis=1))
        rng = np.sort(R[valid] / 1000.0)
        assert np.max(np.abs(dist - rng)) <= 2 * s.beam_origin_m + 1e-4
    assert f"{len(scans)} of {len(scans)} sweeps" in sim["stderr"]


def test_sim_ground_truth_and_extrinsic(sim):
    d, truth = sim["dir"] / "all", sim["truth"]
    gt = np.loadtxt(d / "ground_truth.tum")
    assert len(gt) == len(truth)
    for row, p in zip(gt[[0, -1]], (truth[0], truth[-1])):
        assert row[0] == pytest.approx(p.utime / 1e6, abs=1e-6)
        assert np.allclose(row[1:4], p.position, atol=2e-6)
        w, x, y, z = p.orientation
        assert np.allclose(row[4:8], [x, y, z, w], atol=2e-9)
    veh = yaml.safe_load(VEHICLE.read_text())["sensors"]["lidar"]
    B = np.loadtxt(d / "base_from_lidar.txt", comments="#")
    assert B.shape == (4, 4)
    assert np.allclose(B[:3, 3], veh["xyz"])
    r, pch, y = (math.radians(a) for a in veh["rpy_deg"])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    Ry = np.array([[math.cos(pch), 0, math.sin(pch)], [0, 1, 0], [-math.sin(pch), 0, math.cos(pch)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    assert np.allclose(B[:3, :3], Rz @ Ry @ Rx, atol=1e-8)
    assert "prius2017" in (d / "base_from_lidar.txt").read_text()


def test_every_nth_sweep(sim):
    d, scans = sim["dir"] / "every3", sim["scans"]
    names = sorted(f.name for f in (d / "scans").glob("*.bin"))
    assert names == [f"{k:06d}.bin" for k in range(0, len(scans), 3)]
    times = np.atleast_1d(np.loadtxt(d / "times.txt"))
    assert [round(t * 1e6) for t in times] == [s.utime for s in scans[::3]]
    assert np.array_equal(read_bin(d / "scans" / "000003.bin"), read_bin(sim["dir"] / "all" / "scans" / "000003.bin"))


@pytest.fixture(scope="module")
def hdl(tmp):
    """The HDL-32E pair imported as point sweeps (without --vehicle: the LiDAR's own frame)."""
    d = tmp / "hdl"
    d.mkdir()
    (d / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n")
    run([BIN / "import-scans", "--scans", HDL, "--poses", d / "poses.txt", "--out", d / "pair.lcm", "--quiet"])
    return d


def test_point_sweeps_equal_their_pcd_files(hdl):
    run([EXPORT, "--log", hdl / "pair.lcm", "--out", hdl / "out", "--quiet"])
    for k, pcd in enumerate(sorted(HDL.glob("*.pcd"))):
        src = read_pcd_xyz(pcd)
        keep = np.all(np.isfinite(src), axis=1) & np.any(src != 0, axis=1)   # pb_scan drops these
        pts = read_bin(hdl / "out" / "scans" / f"{k:06d}.bin")
        assert np.array_equal(pts[:, :3], src[keep])
        assert np.all(pts[:, 3] == 0)                 # no per-point times in a PCD without a time field
    B = np.loadtxt(hdl / "out" / "base_from_lidar.txt", comments="#")
    assert np.array_equal(B, np.eye(4))               # imported without --vehicle: GROUND_TRUTH is the LiDAR's
    assert "lidar:imported" in (hdl / "out" / "base_from_lidar.txt").read_text()
    gt = np.loadtxt(hdl / "out" / "ground_truth.tum")
    assert np.allclose(gt[:, 1:4], [[0, 0, 0], [1, 0, 0]])


def test_vehicle_must_match_the_imported_frame(hdl):
    p = run([EXPORT, "--log", hdl / "pair.lcm", "--out", hdl / "v", "--vehicle", VEHICLE], check=False)
    assert p.returncode == 1
    assert "lidar:imported" in p.stderr and "drop --vehicle" in p.stderr


def test_errors(tmp):
    missing = tmp / "no-such.lcm"
    p = run([EXPORT, "--log", missing, "--out", tmp / "x"], check=False)
    assert p.returncode != 0 and str(missing) in p.stderr
    # a log without LIDAR_SCAN
    empty = tmp / "poses-only.lcm"
    w = lcm.EventLog(str(empty), "w", overwrite=True)
    pose = portobello.pose_t()
    pose.utime = 1714572000000000
    pose.orientation = [1.0, 0.0, 0.0, 0.0]
    w.write_event(pose.utime, "GROUND_TRUTH", pose.encode())
    w.close()
    p = run([EXPORT, "--log", empty, "--out", tmp / "y"], check=False)
    assert p.returncode == 1 and "no LIDAR_SCAN" in p.stderr and str(empty) in p.stderr
    # an output folder that cannot be made (its parent is a file)
    blocker = tmp / "a-file"
    blocker.write_text("")
    p = run([EXPORT, "--log", empty, "--out", blocker / "sub"], check=False)
    assert p.returncode == 1 and str(blocker / "sub") in p.stderr
    # a damaged log: the byte offset is named
    bad = tmp / "bad.lcm"
    bad.write_bytes(b"\x00" * 64)
    p = run([EXPORT, "--log", bad, "--out", tmp / "z"], check=False)
    assert p.returncode == 1 and str(bad) in p.stderr and "byte" in p.stderr


def test_help():
    p = run([EXPORT, "--help"])
    assert p.stdout.startswith("usage: scan-export")
    p = run([EXPORT, "--every", "0", "--log", "x", "--out", "y"], check=False)
    assert p.returncode == 2 and "--every" in p.stderr
