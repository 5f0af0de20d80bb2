"""mapper: a site's map from a recorded drive, by LiDAR odometry (bounds about three times
the figures these tests measured, each commented; the module's figures come from
`make bench-mapper`).

The drive is simdrive's (seed 7, normal, 12 s) cut to begin 4 s in, so the car is already
moving at its first sweep; the mapper gets nothing but LIDAR_SCAN."""
import filecmp
import json
import shutil
import subprocess
import time

import lcm
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

import sys
from conftest import BIN, ROOT, run

sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
import locbench as lb  # noqa: E402


def cut_log(src, dst, start_s, channels=None):
    """Copies the events from start_s seconds after the first one (only `channels` if given)."""
    w = lcm.EventLog(str(dst), "w", overwrite=True)
    t0 = None
    for ev in lcm.EventLog(str(src), "r"):
        t0 = ev.timestamp if t0 is None else t0
        if ev.timestamp - t0 >= start_s * 1e6 and (channels is None or ev.channel in channels):
            w.write_event(ev.timestamp, ev.channel, ev.data)
    w.close()
    return dst


def read_tum(path):
    a = np.loadtxt(path, ndmin=2)
    return a[:, 0], a[:, 1:4], Rotation.from_quat(a[:, 4:8])


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("mapdrive")
    lb.make_drive(d, 7, "normal", 12)
    cut = cut_log(d / "drive.lcm", d / "moving.lcm", 4.0, {"LIDAR_SCAN", "GROUND_TRUTH"})
    run([BIN / "pose-to-tum", "--log", cut, "--out", d / "gt.tum", "--channel", "GROUND_TRUTH"])
    out = d / "site"
    p = run([BIN / "mapper", "--log", cut, "--out", out])
    return {"dir": d, "log": cut, "gt": d / "gt.tum", "out": out, "stderr": p.stderr}


def truth_in_map_frame(drive, t):
    """GROUND_TRUTH interpolated at times t, in the mapper's frame (the first pose's base):
    positions and rotations, and the site <- mapper transform."""
    gt_t, gt_p, gt_r = read_tum(drive["gt"])
    assert gt_t[0] <= t[0] and t[-1] <= gt_t[-1], "mapper poses outside GROUND_TRUTH"
    pos = np.stack([np.interp(t, gt_t, gt_p[:, k]) for k in range(3)], axis=1)
    rot = Slerp(gt_t, gt_r)(t)
    r0_inv = rot[0].inv()
    return r0_inv.apply(pos - pos[0]), r0_inv * rot, (rot[0], pos[0])


def test_help_and_bad_options():
    p = run([BIN / "mapper", "--help"])
    assert "--log" in p.stdout and "trajectory.tum" in p.stdout
    p = run([BIN / "mapper", "--out", "x"], check=False)
    assert p.returncode == 2 and "--log" in p.stderr


def test_trajectory_from_a_moving_start(drive):
    t, p, r = read_tum(drive["out"] / "trajectory.tum")
    rep = json.loads((drive["out"] / "report.json").read_text())
    assert rep["scans"] == rep["scans_in_log"] == len(t) == 80
    assert rep["scans_weak"] == 0 and rep["scans_predicted"] == 0
    truth_p, truth_r, _ = truth_in_map_frame(drive, t)
    err = np.linalg.norm(p - truth_p, axis=1)
    path = np.sum(np.linalg.norm(np.diff(truth_p, axis=0), axis=1))
    yaw_err = np.abs((truth_r.inv() * r).as_rotvec()[:, 2]) * 180 / np.pi
    # measured (27 Nov): path 55.1 m, error max 0.062 m (0.1 % of the path), end 0.057 m,
    # yaw max 0.075 deg
    assert path > 50
    assert err.max() < 0.19, f"max {err.max():.3f} m over {path:.1f} m"
    assert yaw_err.max() < 0.22, f"yaw max {yaw_err.max():.3f} deg"


def test_map_lies_on_the_true_surfaces(drive, tmp_path):
    """Every map point, moved into the site's frame with the truth's first pose, against the
    simulated world itself (simdrive --surface-distance: the drive day's ground and objects)."""
    pts = lb.read_pcd(drive["out"] / "map.pcd")[:, :3]
    t, _, _ = read_tum(drive["out"] / "trajectory.tum")
    _, _, (r0, p0) = truth_in_map_frame(drive, t)
    (r0.apply(pts) + p0).astype("<f4").tofile(tmp_path / "map.f32")
    p = run([BIN / "simdrive", "--site", ROOT / "maps" / "default", "--surface-distance", tmp_path / "map.f32"])
    d = json.loads(p.stdout)
    # measured (27 Nov): 648,566 points, 91.1 % within 5 cm of a true surface (median 8.6 mm),
    # 1.25 % farther than 0.5 m (traffic the carving left; 8 s of drive give it few rays); the
    # site's own map, mapped on another day: 98.9 % within 5 cm. Bounds: three times the
    # share outside 5 cm, the share beyond 0.5 m and the median
    assert d["points"] == len(pts) > 300000
    assert d["within_0.05"] > 0.73, d
    assert d["beyond_0.5"] < 0.0375, d
    assert d["median_m"] < 0.026, d


def test_gnss_anchoring_writes_the_geo_reference(drive, tmp_path):
    """With the drive's GNSS_FIX the map is moved onto the fixes and site.yaml holds the
    geo-reference; the trajectory, taken through it and the default site's to the truth's
    frame, lies where the truth does within what 8 s of GNSS can tell."""
    import yaml
    sys.path.insert(0, str(ROOT / "modules" / "mapper" / "bench"))
    import trajmetrics as tm
    log = cut_log(drive["dir"] / "drive.lcm", tmp_path / "with_gnss.lcm", 4.0, {"LIDAR_SCAN", "GNSS_FIX"})
    run([BIN / "mapper", "--log", log, "--out", tmp_path / "site", "--quiet"])
    rep = json.loads((tmp_path / "site" / "report.json").read_text())
    assert rep["geo_referenced"] is True and rep["gnss_fixes_used"] >= 70 and rep["gnss_fixes_gated"] == 0
    mine = yaml.safe_load((tmp_path / "site" / "site.yaml").read_text())["georef"]
    default = yaml.safe_load((ROOT / "maps" / "default" / "site.yaml").read_text())["georef"]
    t, P = tm.read_tum(tmp_path / "site" / "trajectory.tum")
    gt_t, gt_P = tm.read_tum(drive["gt"])
    ok, G = tm.poses_at(gt_t, gt_P, t)
    Q = tm.site_from_site(default, mine) @ P[ok]
    horiz = np.linalg.norm(Q[:, :2, 3] - G[:, :2, 3], axis=1)
    yaw = np.degrees(np.arctan2(Q[:, 1, 0], Q[:, 0, 0]) - np.arctan2(G[:, 1, 0], G[:, 0, 0]))
    yaw = np.abs((yaw + 180) % 360 - 180)
    # measured (27 Nov): horizontal 3.05 m median, 3.18 m max, yaw 0.13 deg: 8 s of fixes whose
    # error (1.5 m an axis) keeps for about 20 s cannot place the map better; over the 232 s
    # loop of bench-mapper it is 0.8 m
    assert horiz.max() < 9.5
    assert np.median(yaw) < 0.4
    # the folder is a site: the localizer loads it (its tiles, no preparing) and starts from GNSS
    for f in ("map.pcd", "map.tiles", "ground.yaml", "ground.pgm", "trajectory.tum", "odometry.tum"):
        assert (tmp_path / "site" / f).stat().st_size > 0, f
    assert (tmp_path / "site" / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = run([BIN / "localizer", "--site", tmp_path / "site", "--replay", log, "--out", tmp_path / "loc.lcm"])
    assert "map.tiles" in p.stderr and "preparing" not in p.stderr
    st = lb.read_poses(tmp_path / "loc.lcm", "POSE")[:, 5]
    # measured (27 Nov): 78 of 80 POSE tracking (the GNSS start takes two sweeps)
    assert np.mean(st == 1) > 0.9, np.bincount(st.astype(int))
    # without GNSS (the fixture's log): no site.yaml, and the report says why
    rep0 = json.loads((drive["out"] / "report.json").read_text())
    assert rep0["geo_referenced"] is False and "no GNSS_FIX" in rep0["geo_reference_why_not"]
    assert not (drive["out"] / "site.yaml").exists()


def test_same_drive_same_map(drive, tmp_path):
    run([BIN / "mapper", "--log", drive["log"], "--out", tmp_path, "--quiet"])
    assert filecmp.cmp(tmp_path / "trajectory.tum", drive["out"] / "trajectory.tum", shallow=False)
    assert filecmp.cmp(tmp_path / "map.pcd", drive["out"] / "map.pcd", shallow=False)


def test_restart_after_a_kill(drive, tmp_path):
    """Killed (SIGKILL) in the middle of the odometry and run again, the mapper resumes from its
    checkpoint and writes the same site as the uninterrupted run (the fixture's), byte for byte;
    a checkpoint of another log is refused and the run starts over."""
    out = tmp_path / "site"
    cmd = [str(BIN / "mapper"), "--log", str(drive["log"]), "--out", str(out), "--checkpoint-every", "20"]
    p = subprocess.Popen(cmd + ["--quiet"])
    ck = out / "checkpoint.bin"
    deadline = time.monotonic() + 120
    while p.poll() is None and not ck.exists() and time.monotonic() < deadline:
        time.sleep(0.002)
    p.kill()
    p.wait()
    assert ck.exists() and (out / "keyframes.bin").exists() and not (out / "map.pcd").exists()
    shutil.copytree(out, tmp_path / "other")
    q = run(cmd)
    rep = json.loads((out / "report.json").read_text())
    # killed at the first checkpoint (20 of the 80 sweeps) or the next
    assert 0 < rep["resumed_from_scan"] < 80 and rep["checkpoint_refused"] == "", rep
    assert f"resuming from {ck}: {rep['resumed_from_scan']} of 80 scans read" in q.stderr, q.stderr
    for f in ("trajectory.tum", "odometry.tum", "map.pcd", "map.tiles", "ground.pgm"):
        assert filecmp.cmp(out / f, drive["out"] / f, shallow=False), f
    assert not ck.exists() and not (out / "keyframes.bin").exists()   # a finished run leaves none
    # the checkpoint with another log (the same drive from 1 s later): refused, started over
    log2 = cut_log(drive["log"], tmp_path / "later.lcm", 1.0)
    q = run([BIN / "mapper", "--log", log2, "--out", tmp_path / "other", "--quiet"])
    rep = json.loads((tmp_path / "other" / "report.json").read_text())
    assert rep["resumed_from_scan"] == 0 and "from another log" in rep["checkpoint_refused"], rep
    assert "from another log" in q.stderr and "starting over" in q.stderr, q.stderr
    assert rep["scans"] < 80


def test_bad_input(drive, tmp_path):
    p = run([BIN / "mapper", "--log", tmp_path / "missing.lcm", "--out", tmp_path / "o"], check=False)
    assert p.returncode == 1 and "missing.lcm" in p.stderr
    # no LIDAR_SCAN at all
    gt_only = cut_log(drive["log"], tmp_path / "gt_only.lcm", 0, {"GROUND_TRUTH"})
    p = run([BIN / "mapper", "--log", gt_only, "--out", tmp_path / "o"], check=False)
    assert p.returncode == 1 and "no LIDAR_SCAN" in p.stderr
    # a recording cut inside its last sweep (power loss): a map of what is there, and a warning
    torn = tmp_path / "torn.lcm"
    data = drive["log"].read_bytes()
    torn.write_bytes(data[: len(data) // 2 + 1234])
    p = run([BIN / "mapper", "--log", torn, "--out", tmp_path / "torn"], check=False)
    assert p.returncode == 0 and "torn" in p.stderr
    assert json.loads((tmp_path / "torn" / "report.json").read_text())["scans"] > 10
    # a damaged byte in the middle: an error naming the byte, nothing written
    bad = bytearray(data)
    sync = data.find(b"\xed\xa1\xda\x01", len(data) // 2)   # an event header's sync word
    bad[sync] ^= 0xFF
    bad_log = tmp_path / "damaged.lcm"
    bad_log.write_bytes(bytes(bad))
    p = run([BIN / "mapper", "--log", bad_log, "--out", tmp_path / "dmg"], check=False)
    assert p.returncode == 1 and "byte" in p.stderr, p.stderr
    assert not (tmp_path / "dmg" / "map.pcd").exists()
    # an output folder that cannot be made
    (tmp_path / "file").write_text("x")
    p = run([BIN / "mapper", "--log", drive["log"], "--out", tmp_path / "file" / "site"], check=False)
    assert p.returncode == 1 and "file/site" in p.stderr
