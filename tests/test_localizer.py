"""Localizer integration tests on a short simulated drive (bounds about three times the
figures these tests measured, each commented; the module's figures are measured by
`make bench-localizer-drive`).

The site is the default site with its prior map cropped to the drive's surroundings
(so each run loads in about a second); the drive is simdrive (12 s, normal profile)
with VEHICLE_SPEED added by `can --replay` and `log-merge`."""
import json
import math
import os
import re
import shutil
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from conftest import BIN, MULRAN, ROOT, read_log, run

sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
import bench_starts as bs  # noqa: E402
import keyframe_site  # noqa: E402
import locbench as lb  # noqa: E402
import real_starts  # noqa: E402
import reference  # noqa: E402
import bench_gicp  # noqa: E402

FAULT = ROOT / "tools" / "log-fault" / "log_fault.py"


def write_cropped_map(gt, path, margin=70):
    """The default map cropped to the drive's surroundings: it loads in about a second."""
    lb.crop_map(ROOT / "maps" / "default" / "map.pcd", gt, path, margin)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("locdrive")
    log = lb.make_drive(d, 7, "normal", 12)
    gt = lb.read_poses(d / "drive.lcm", "GROUND_TRUTH")
    site = d / "site"
    site.mkdir()
    for name in ("site.yaml", "route.yaml", "world.yaml"):
        shutil.copy(ROOT / "maps" / "default" / name, site / name)
    write_cropped_map(gt, site / "map.pcd")
    # the site as make prepares one: map.tiles next to map.pcd (the folder with map.pcd
    # alone is prepared by the localizer at start-up)
    run([BIN / "map-tiles", "--map", site / "map.pcd", "--out", site / "map.tiles", "--quiet"])
    only_map = d / "only_map"
    only_map.mkdir()
    shutil.copy(site / "map.pcd", only_map / "map.pcd")
    return {"dir": d, "log": log, "drive": d / "drive.lcm", "gt": gt, "site": site, "only_map": only_map}


def localize(drive, inp, out, *extra, site=None):
    p = run([BIN / "localizer", "--site", site or drive["site"], "--replay", inp, "--out", out, *extra],
            check=False, timeout=300)
    assert p.returncode == 0, p.stderr
    return p


def statuses(path):
    return [int(s) for s in lb.read_poses(path, "POSE")[:, 5]]


def last_status_msg(path):
    from portobello import status_t
    msgs = [status_t.decode(d) for ch, _, d in read_log(path, {"STATUS"})]
    assert msgs, "no STATUS in the output"
    return msgs[-1]


def counters(msg):
    return dict(zip(msg.counter_names, msg.counter_values))


def test_help_and_bad_options():
    p = run([BIN / "localizer", "--help"])
    assert "--replay" in p.stdout and "--initial-pose" in p.stdout
    p = run([BIN / "localizer", "--initial-pose", "1,2,3"], check=False)
    assert p.returncode == 2 and "--initial-pose" in p.stderr
    p = run([BIN / "localizer", "--replay", "x.lcm"], check=False)
    assert p.returncode == 2


def test_gnss_start_tracks_accurately_and_deterministically(drive, tmp_path):
    out1, out2 = tmp_path / "a.lcm", tmp_path / "b.lcm"
    localize(drive, drive["log"], out1)
    r = lb.score_run(drive["drive"], out1)
    n_scans = sum(1 for _ in read_log(drive["drive"], {"LIDAR_SCAN"}))
    assert r["poses"] == n_scans, "one POSE per sweep"
    # bounds ~3x the figures measured on this drive (27 Nov 2026; replay is deterministic):
    # tracking after 0.2 s, median 0.005 m, p99 0.009 m, yaw p99 0.006 deg
    assert r["first_tracking_s"] <= 0.6, r
    assert r["lost_after_tracking"] == 0 and r["not_tracking_after"] == 0
    assert r["t_median"] < 0.015 and r["t_p99"] < 0.03 and r["yaw_p99"] < 0.02, r
    assert r["pred_rate_hz"] >= 190, r
    st = last_status_msg(out1)
    assert st.module == "localizer"
    assert {i.channel for i in st.inputs} >= {"LIDAR_SCAN", "IMU", "GNSS_FIX", "VEHICLE_SPEED"}
    # replay is deterministic: the same input gives the same bytes
    localize(drive, drive["log"], out2)
    assert out1.read_bytes() == out2.read_bytes()


def test_site_with_only_a_map_and_lidar_alone(drive, tmp_path):
    out = tmp_path / "o.lcm"
    x, y, z, yaw = drive["gt"][0, 1:5]
    p = localize(drive, drive["log"], out, "--no-imu", "--no-speed",
                 f"--initial-pose={x},{y},{z},0,0,{math.degrees(yaw)}", site=drive["only_map"])
    assert "no site.yaml" in p.stderr
    r = lb.score_run(drive["drive"], out)
    # measured: tracking after 0.2 s, median 0.010 m, p99 0.040 m (LiDAR alone)
    assert r["first_tracking_s"] <= 0.6 and r["lost_after_tracking"] == 0, r
    assert r["t_median"] < 0.03 and r["t_p99"] < 0.12, r
    # without IMU, POSE_PREDICTED still comes at 200 Hz from the timer
    assert r["pred_rate_hz"] >= 190


def test_raw_sweeps_without_point_times_deskewed_from_azimuth(drive, tmp_path):
    """A dataset's raw sweeps as x y z only (no point times), imported with import-scans
    --spin: each point's time from its azimuth. LiDAR alone from the true start, as well as
    the sweeps with their own times; imported without --spin (every point at the sweep's
    start, right only for motion-compensated scans) the same drive is metres off."""
    exp = tmp_path / "export"
    run([BIN / "scan-export", "--log", drive["drive"], "--out", exp, "--quiet"])
    lb.lidar_poses_tum(exp, tmp_path / "lidar.tum")
    x, y, z, yaw = drive["gt"][0, 1:5]
    results = {}
    for name, extra in (("azimuth", ["--spin", "cw"]), ("none", [])):
        log, out = tmp_path / f"{name}.lcm", tmp_path / f"{name}.out.lcm"
        run([BIN / "import-scans", "--scans", exp / "scans", "--poses", tmp_path / "lidar.tum", "--times",
             exp / "times.txt", "--vehicle", ROOT / "vehicles" / "prius2017.yaml", "--out", log, "--quiet",
             "--bin-fields", "x,y,z,_", *extra])
        localize(drive, log, out, "--no-imu", "--no-speed", "--no-gnss", f"--initial-pose={x},{y},{z},0,0,{math.degrees(yaw)}")
        results[name] = lb.score_run(log, out)
    r = results["azimuth"]
    # measured: median 0.010 m, p99 0.042 m, tracking after 0.2 s, no LOST (the sweeps with
    # their own times, test_site_with_only_a_map_and_lidar_alone: 0.010 / 0.040 m)
    assert r["first_tracking_s"] <= 0.6 and r["lost_after_tracking"] == 0 and r["not_tracking_after"] == 0, r
    assert r["t_median"] < 0.03 and r["t_p99"] < 0.13, r
    # measured without times: median 0.33 m, p99 0.81 m: the drive is fast enough to show it
    assert results["none"]["t_p99"] > 0.3, results["none"]


def test_lidar_gap_runs_on_prediction(drive, tmp_path):
    flog, out = tmp_path / "gap.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "lidar-gap", "--in", drive["log"], "--out", flog, "--at", "4", "--for", "3"])
    localize(drive, flog, out)
    poses = lb.read_poses(out, "POSE")
    t0 = lb.read_channel_times(flog, "IMU")[0]
    gap = poses[(poses[:, 0] > t0 + 4.3e6) & (poses[:, 0] < t0 + 7e6)]
    assert len(gap) >= 20, "POSE goes on during the gap"
    assert set(gap[:, 5]) == {2}, "degraded while the LiDAR is missing"
    pg, _, _ = lb.errors_vs_truth(gap, drive["gt"])
    t = pg[-1, 0]
    eh = math.hypot(pg[-1, 1] - np.interp(t, drive["gt"][:, 0], drive["gt"][:, 1]),
                    pg[-1, 2] - np.interp(t, drive["gt"][:, 0], drive["gt"][:, 2]))
    ez = abs(pg[-1, 3] - np.interp(t, drive["gt"][:, 0], drive["gt"][:, 3]))
    # measured at the gap's end 0.031 m across the ground and 0.129 m in height: 4 s into
    # the drive the accelerometer's vertical bias is not yet learnt, and nothing but the
    # sweeps holds the height (the body pitches, so CAN speed says nothing of it)
    assert eh < 0.1 and ez < 0.4, (eh, ez)
    after = poses[poses[:, 0] >= t0 + 7e6]
    assert after[1, 5] == 1 or after[0, 5] == 1, "tracking again within 2 sweeps"
    assert counters(last_status_msg(out)).get("lidar_gap") == 1


def test_wrong_initial_pose_is_reported_lost_and_relocalized(drive, tmp_path):
    flog, out = tmp_path / "jump.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "jump", "--in", drive["log"], "--out", flog, "--at", "4", "--metres", "20"])
    localize(drive, flog, out)
    tj = lb.read_events(flog, ["INITIAL_POSE"])[0][0]
    poses = lb.read_poses(out, "POSE")
    after = poses[poses[:, 0] >= tj]
    lost = np.nonzero(after[:, 5] == 3)[0]
    assert len(lost) and (after[lost[0], 0] - tj) <= 0.3e6, "lost within 0.3 s (measured 0.1 s)"
    back = np.nonzero(after[lost[0]:, 5] == 1)[0]
    assert len(back) and (after[lost[0] + back[0], 0] - tj) <= 1e6, "relocalized within 1 s (measured 0.3 s)"
    _, et, _ = lb.errors_vs_truth(after[after[:, 5] == 1], drive["gt"])
    assert et.max() < 0.03, ("never tracking at the wrong pose (measured max 0.009 m)", et.max())


def test_kidnapped_car_is_reported_lost_and_relocalized(drive, tmp_path):
    """The car's data skips 1.5 s ahead at 6 s (12 m along the road at 8.5 m/s) while it is
    tracked, every sensor healthy and no GNSS: the pose held is suddenly wrong and only the
    map can tell (the ground fits all along the road, and the IMU and CAN go on as smoothly as
    before). Its sweeps fail the structure test: ten in a row make it LOST, and it is found
    again; never TRACKING at the wrong pose. Following the sweeps the structure test could not
    verify, instead of counting them, held such a pose for 6-12 s, and with no LOST within
    this log this test failed (docs/history/localizer.md, "A street without buildings or
    trees")."""
    flog = tmp_path / "kidnap.lcm"
    run([sys.executable, FAULT, "kidnap", "--in", drive["log"], "--out", flog, "--at", "6", "--for", "1.5"])
    gt = lb.read_poses(flog, "GROUND_TRUTH")
    tk = lb.read_events(flog, ["GROUND_TRUTH"])[0][0] + 6e6
    start = f"--initial-pose={gt[0, 1]},{gt[0, 2]},{gt[0, 3]},0,0,{math.degrees(gt[0, 4])}"
    # measured: LOST 1.0 s after (ten sweeps), tracking again 1.6 s (LiDAR alone) and 2.2 s
    # (IMU + CAN) after, at most 0.047 and 0.007 m off then
    for mode, extra, err_m in (("lidar", ("--no-imu", "--no-speed"), 0.15), ("fused", (), 0.03)):
        out = tmp_path / f"o_{mode}.lcm"
        localize(drive, flog, out, "--no-gnss", start, *extra)
        poses, et, _ = lb.errors_vs_truth(lb.read_poses(out, "POSE"), gt)
        before, after = poses[:, 0] < tk - 2e4, poses[:, 0] >= tk
        assert np.all(poses[before][-20:, 5] == 1) and et[before & (poses[:, 5] == 1)].max() < err_m, (mode, "tracked before")
        lost = np.nonzero(after & (poses[:, 5] == 3))[0]
        assert len(lost) and poses[lost[0], 0] - tk <= 1.5e6, (mode, "LOST within 1.5 s")
        back = np.nonzero((np.arange(len(poses)) > lost[0]) & (poses[:, 5] == 1))[0]
        assert len(back) and poses[back[0], 0] - tk <= 3.5e6, (mode, "tracking again within 3.5 s")
        trk = after & (poses[:, 5] == 1)
        assert et[trk].max() < err_m, (mode, "never tracking at the wrong pose", et[trk].max())


def test_gnss_jump_is_not_followed(drive, tmp_path):
    """GNSS moved 20 m (multipath, spoofing) while the map fits: the pose stays, the fixes are counted as outliers."""
    flog, out = tmp_path / "gj.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "gnss-jump", "--in", drive["log"], "--out", flog, "--at", "4", "--for", "4"])
    localize(drive, flog, out)
    r = lb.score_run(drive["drive"], out)
    assert r["lost_after_tracking"] == 0 and r["not_tracking_after"] == 0
    assert r["t_p99"] < 0.03, r      # measured 0.009 m
    assert counters(last_status_msg(out)).get("gnss_outlier", 0) > 0


def test_bad_input_is_counted_not_fatal(drive, tmp_path):
    steps = [("nan-points", ["--at", "2", "--count", "2"]), ("empty-scans", ["--at", "3", "--count", "2"]),
             ("duplicate", ["--at", "4", "--for", "0.5"]), ("reorder", ["--at", "5", "--for", "0.5"]),
             ("imu-gap", ["--at", "6", "--for", "0.3"]), ("garbage", ["--at", "7", "--count", "1"])]
    cur = drive["log"]
    for i, (fault, args) in enumerate(steps):
        nxt = tmp_path / f"f{i}.lcm"
        run([sys.executable, FAULT, fault, "--in", cur, "--out", nxt, *args])
        cur = nxt
    out = tmp_path / "o.lcm"
    p = localize(drive, cur, out)
    c = counters(last_status_msg(out))
    for name in ("scan_nonfinite_points", "scan_empty", "imu_duplicate", "scan_duplicate", "imu_out_of_order",
                 "imu_gap", "undecodable"):
        assert c.get(name, 0) > 0, (name, c)
    assert "NaN/inf points" in p.stderr and "IMU: gap" in p.stderr and "does not decode" in p.stderr
    s = statuses(out)
    assert s[-1] == 1 and 3 not in s, "keeps tracking through bad input"
    r = lb.score_run(drive["drive"], out)
    assert r["t_p99"] < 0.03, r      # measured 0.010 m


@pytest.mark.parametrize("what", ["missing", "corrupt", "not-a-pcd", "no-site"])
def test_map_missing_or_corrupt(drive, tmp_path, what):
    site = tmp_path / "site"
    if what != "no-site":
        site.mkdir()
    if what == "corrupt":
        (site / "map.pcd").write_bytes(b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                                      b"WIDTH 100\nHEIGHT 1\nPOINTS 100\nDATA binary\n" + b"\x00" * 40)
    if what == "not-a-pcd":   # PCL's reader crashed on it; the header is read first now
        (site / "map.pcd").write_bytes(b"garbage\n")
    out = tmp_path / "o.lcm"
    p = run([BIN / "localizer", "--site", site, "--replay", drive["log"], "--out", out], check=False, timeout=60)
    assert p.returncode == 1
    assert str(site) in p.stderr
    st = last_status_msg(out)
    assert st.state == st.STATE_ERROR and str(site) in st.last_error


def test_tiles_of_another_map_are_refused(drive, tmp_path):
    """A map.tiles prepared from another map.pcd (an edited map, a copied site) is an error
    naming both files, never used; a site with map.pcd alone is prepared at start-up."""
    site = tmp_path / "site"
    site.mkdir()
    for name in ("site.yaml", "map.tiles"):
        shutil.copy(drive["site"] / name, site / name)
    pts = lb.read_pcd(drive["site"] / "map.pcd")
    lb.write_pcd(site / "map.pcd", pts[:-1])   # one point less: another map
    out = tmp_path / "o.lcm"
    p = run([BIN / "localizer", "--site", site, "--replay", drive["log"], "--out", out], check=False, timeout=60)
    assert p.returncode == 1
    assert "prepared from another map" in p.stderr and str(site / "map.pcd") in p.stderr, p.stderr
    st = last_status_msg(out)
    assert st.state == st.STATE_ERROR and str(site / "map.tiles") in st.last_error
    # only map.pcd: prepared into a temporary tile file, said on stderr, tracks as usual
    (site / "map.tiles").unlink()
    p = localize(drive, drive["log"], out, site=site)
    assert "no map.tiles" in p.stderr
    assert lb.score_run(drive["drive"], out)["t_p99"] < 0.03     # measured 0.009 m


def run_rss(args):
    """Runs a command; returns (stderr, returncode, peak RSS in MB). The peak is VmHWM of
    /proc/PID/status, polled while it runs (it only grows; reset at exec, so the forking
    test process's own memory does not count, unlike ru_maxrss)."""
    pr = subprocess.Popen([str(a) for a in args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    hwm = [0]

    def poll():
        while pr.poll() is None:
            try:
                if os.readlink(f"/proc/{pr.pid}/exe") != str(args[0]):
                    continue   # not exec'd yet: the forked test process
                for line in open(f"/proc/{pr.pid}/status"):
                    if line.startswith("VmHWM:"):
                        hwm[0] = max(hwm[0], int(line.split()[1]))
            except OSError:
                pass
            finally:
                time.sleep(0.02)

    th = threading.Thread(target=poll)
    th.start()
    err = pr.stderr.read()
    pr.wait(timeout=300)
    th.join()
    return err, pr.returncode, hwm[0] / 1024.0


def test_default_site_is_paged(drive, tmp_path):
    """The full default site (maps/default with the map.tiles make builds): the localizer holds
    only the tiles around the car, loads and drops them (STATUS counters) and stays small."""
    out = tmp_path / "o.lcm"
    site = ROOT / "maps" / "default"
    err, rc, peak = run_rss([BIN / "localizer", "--site", site, "--replay", drive["log"], "--out", out, "--verbose"])
    assert rc == 0, err
    assert "paged within 120 m" in err and "map tiles around" in err
    c = counters(last_status_msg(out))
    assert c.get("map_tile_loaded", 0) > 0, c
    r = lb.score_run(drive["drive"], out)
    # measured: tracking after 0.2 s, median 0.005 m, p99 0.009 m
    assert r["first_tracking_s"] <= 0.6 and r["lost_after_tracking"] == 0, r
    assert r["t_median"] < 0.015 and r["t_p99"] < 0.03, r
    # measured (28 Nov 2026, a place descriptor every metre: 121,082 places of 52 bytes):
    # peak RSS 56 MB on this 12 s drive, 58 MB on the 232 s lap (bench-localizer-memory;
    # every tile held: 116 MB); 150 MB is the target
    print(f"default site, GNSS start, 12 s: peak RSS {peak:.1f} MB")
    assert peak < 150, peak


def test_no_prior_start_on_the_paged_default_site(drive, tmp_path):
    """No prior, LiDAR alone, on the full default site: the global search tries places all
    over the map, paging their tiles in and out, and finds the car; memory stays bounded
    (before the descriptors were stored with the tiles, building them peaked at 387 MB)."""
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut(drive, log, 5, 6, "LIDAR_SCAN,GROUND_TRUTH")
    err, rc, peak = run_rss([BIN / "localizer", "--site", ROOT / "maps" / "default", "--replay", log, "--out", out])
    assert rc == 0, err
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    # measured: tracking after 0.3 s (0.6 s with a place every 3 m: found on the 4th sweep),
    # max error 0.067 m, peak RSS 56 MB; 150 MB is the target
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 1.0e6, "tracking within 1 s"
    _, et, _ = lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], drive["gt"])
    assert et.max() < 0.2, et.max()
    c = counters(last_status_msg(out))
    assert c.get("map_tile_loaded", 0) > 0 and c.get("map_tile_dropped", 0) > 0, c
    print(f"default site, no prior: tracking after {(poses[k, 0] - poses[0, 0]) * 1e-6:.1f} s, peak RSS {peak:.1f} MB")
    assert peak < 150, peak


def test_pose_to_tum(drive, tmp_path):
    tum = tmp_path / "gt.tum"
    p = run([BIN / "pose-to-tum", "--log", drive["drive"], "--channel", "GROUND_TRUTH", "--out", tum])
    lines = tum.read_text().splitlines()
    assert len(lines) == len(drive["gt"]) and "poses of GROUND_TRUTH" in p.stderr
    # the same numbers simdrive wrote to its own TUM file
    ref = np.loadtxt(drive["dir"] / "ground_truth.tum")
    got = np.loadtxt(tum)
    assert np.allclose(got, ref, atol=1e-5)
    assert run([BIN / "pose-to-tum", "--help"]).stdout.startswith("usage")
    # Garbage inside the log is an error naming the byte; a log that ends inside its last
    # event (a recording cut short) is read up to the cut with a warning naming the byte.
    raw = drive["drive"].read_bytes()
    bad = tmp_path / "bad.lcm"
    bad.write_bytes(raw[:100000] + b"garbage" * 10 + raw[100000:])
    p = run([BIN / "pose-to-tum", "--log", bad, "--channel", "GROUND_TRUTH", "--out", tmp_path / "b.tum"], check=False)
    assert p.returncode == 1 and "byte" in p.stderr
    bad.write_bytes(raw[:100000])
    p = run([BIN / "pose-to-tum", "--log", bad, "--channel", "GROUND_TRUTH", "--out", tmp_path / "b.tum"], check=False)
    assert p.returncode == 0 and "warning: the last event is torn" in p.stderr


LIVE_URL = "udpm://239.255.76.67:7760?ttl=0&recv_buf_size=8388608"


def live_handlers(got):
    """Decoders for the POSE-like and STATUS channels of `got` (channel -> list)."""
    from portobello import pose_t, status_t

    def handler(ch, data):
        got[ch].append(status_t.decode(data) if ch == "STATUS" else pose_t.decode(data))
    return {ch: handler for ch in got}


def wait_heartbeat(got):
    deadline = time.time() + 60   # map loaded, heartbeat running
    while not got["STATUS"] and time.time() < deadline:
        time.sleep(0.1)
    assert got["STATUS"], "no STATUS heartbeat"


@pytest.mark.live
def test_live_bus(drive, tmp_path):
    """Live: the first 3 s of the drive published on a private bus; POSE, POSE_PREDICTED and
    STATUS come back, and SIGINT stops the localizer cleanly. Counts are loose (UDP)."""
    import signal

    from portobello import pose_t
    got = {"POSE": [], "POSE_PREDICTED": [], "STATUS": []}
    with lb.Listener(LIVE_URL, live_handlers(got)) as lc:
        proc = subprocess.Popen([str(BIN / "localizer"), "--site", str(drive["site"]), "--lcm-url", LIVE_URL],
                                stderr=subprocess.PIPE, text=True)
        try:
            wait_heartbeat(got)
            events = [e for e in read_log(drive["log"], {"IMU", "LIDAR_SCAN", "GNSS_FIX", "VEHICLE_SPEED"})]
            t_first = events[0][1]
            start = time.time()
            for ch, ts, data in events:
                if ts - t_first > 3e6:
                    break
                delay = (ts - t_first) * 1e-6 - (time.time() - start)
                if delay > 0:
                    time.sleep(delay)
                lc.publish(ch, data)
            time.sleep(1.0)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=10) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
    assert len(got["POSE"]) >= 12, len(got["POSE"])                          # measured 38
    assert len(got["POSE_PREDICTED"]) >= 240, len(got["POSE_PREDICTED"])      # measured 716
    assert any(p.status == pose_t.STATUS_TRACKING for p in got["POSE"]), [p.status for p in got["POSE"]]
    assert got["STATUS"][-1].module == "localizer"


STALE_URL = "udpm://239.255.76.67:7761?ttl=0&recv_buf_size=8388608"


@pytest.mark.live
def test_live_search_skips_sweeps_that_went_stale_in_the_queue(drive, tmp_path):
    """Live with no prior, LiDAR alone: a global search can cost hundreds of ms a sweep (a
    second on a loaded machine), and sweeps queue meanwhile. Searching each queued sweep in
    turn would leave the car ever further behind; the stale ones are skipped (counted in
    STATUS) and the newest searched, so no POSE comes much later than its sweep. The stall
    is made certain: the localizer is stopped (SIGSTOP) while 10 sweeps arrive, then
    continued; then sweeps come at 10 Hz for 8 s and are searched until tracked."""
    import signal

    from portobello import lidar_scan_t, pose_t
    got = {"POSE": [], "STATUS": []}
    arrived = {}                      # POSE utime -> wall time received
    handlers = live_handlers(got)
    pose_handler = handlers["POSE"]

    def on_pose(ch, data):
        pose_handler(ch, data)
        arrived[got["POSE"][-1].utime] = time.monotonic()
    handlers["POSE"] = on_pose
    scans = [d for _, _, d in read_log(drive["log"], {"LIDAR_SCAN"})][:90]
    sent = []                         # (sweep utime, wall time published)
    err = tmp_path / "err.txt"
    with lb.Listener(STALE_URL, handlers) as lc, open(err, "w") as errf:
        proc = subprocess.Popen([str(BIN / "localizer"), "--site", str(drive["site"]), "--lcm-url", STALE_URL,
                                 "--no-imu", "--no-speed", "--no-gnss", "--verbose"], stderr=errf)
        try:
            wait_heartbeat(got)
            proc.send_signal(signal.SIGSTOP)
            for i, d in enumerate(scans):
                if i == 10:           # the first 10 waited in the socket while the localizer stalled
                    time.sleep(0.5)
                    proc.send_signal(signal.SIGCONT)
                sent.append((lidar_scan_t.decode(d).utime, time.monotonic()))
                lc.publish("LIDAR_SCAN", d)
                time.sleep(0.01 if i < 10 else 0.1)
            time.sleep(1.5)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(timeout=10) == 0
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)
                proc.kill()
    c = counters(got["STATUS"][-1])
    stalled_end = sent[9][0] + 100000
    searched = sum(1 for p in got["POSE"] if p.utime <= stalled_end)
    # how late each sweep's POSE came: from the sweep's publication (the stall included)
    late = [arrived[p.utime] - max(w for u, w in sent if u <= p.utime) for p in got["POSE"]
            if p.utime in arrived and any(u <= p.utime for u, _ in sent)]
    trk = [p.utime for p in got["POSE"] if p.status == pose_t.STATUS_TRACKING]
    print(f"skipped {c.get('scan_stale_skipped', 0)} stale sweeps; {searched} of the 10 stalled searched; "
          f"POSE late by at most {max(late):.2f} s; tracking {(trk[0] - stalled_end) * 1e-6 if trk else -1:.1f} s "
          f"after the stalled sweeps")
    # measured (machine loaded by other builds and tests, 4 runs): 15-19 skipped (the stalled
    # ones and 10 Hz sweeps that came during a search), 1-2 of the stalled searched (LCM
    # stamps a message when its thread reads it: the first read after SIGCONT is fresh), POSE
    # late by at most 1.5-1.8 s (one search); tracking 0.8-1.2 s after the stall when the
    # machine was less loaded (the search's speed, not the skip, sets that). The lateness
    # bound is under 2x the measured figure on purpose: searching the 10 stalled sweeps in
    # turn (no skip) makes the last of them 10 searches late, 5-10 s here.
    assert c.get("scan_stale_skipped", 0) >= 6, c     # measured 18
    assert searched <= 2, searched
    assert max(late) < 3.0, late
    assert trk, ([p.status for p in got["POSE"]], err.read_text())


# ---------------------------------------------------------------- starts like real life, honest failure

def cut(drive, out, at, dur, keep):
    run([sys.executable, FAULT, "cut", "--in", drive["log"], "--out", out, "--at", str(at), "--for", str(dur),
         "--keep", keep])


def first_tracking(poses):
    trk = np.nonzero(poses[:, 5] == 1)[0]
    return trk[0] if len(trk) else None


def test_moving_lidar_only_start_from_a_rough_prior(drive, tmp_path):
    """Cut 6 s into the drive (the car moving), LIDAR_SCAN alone, a guess 3 m and 15 degrees off:
    the guess is a prior, not a truth, so the start converges on the true pose."""
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut(drive, log, 6, 5, "LIDAR_SCAN,GROUND_TRUTH")
    t_scan = lb.read_channel_times(log, "LIDAR_SCAN")[0]
    g = drive["gt"][np.searchsorted(drive["gt"][:, 0], t_scan)]
    i = np.searchsorted(drive["gt"][:, 0], t_scan)
    speed = np.hypot(*(drive["gt"][i + 1, 1:3] - drive["gt"][i, 1:3])) / ((drive["gt"][i + 1, 0] - drive["gt"][i, 0]) * 1e-6)
    assert speed > 3, "the start is a moving one"
    x, y = g[1] + 3 * math.cos(2.0), g[2] + 3 * math.sin(2.0)
    yaw = math.degrees(g[4]) + 15
    localize(drive, log, out, f"--initial-pose={x},{y},{g[3] + 0.8},0,0,{yaw}")
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    # measured: tracking at the 3rd sweep (0.2 s), worst error while tracking 0.0xx m
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 1.0e6, "tracking within 1 s"
    _, et, ey = lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], drive["gt"])
    assert et.max() < 0.12 and ey.max() < 0.2, (et.max(), ey.max())     # measured 0.041 m, 0.069 deg
    assert 3 not in poses[k:, 5]


def test_moving_start_on_sparse_sweeps(drive, tmp_path):
    """One sweep a second (keyframes, or sweeps skipped while a live search ran), the car
    moving, LiDAR alone, a prior 3 m and 15 degrees off: the second sweep is searched as far
    along the car's axis as it can have gone (metres), and the track holds."""
    import lcm
    log, thin, out = tmp_path / "cut.lcm", tmp_path / "thin.lcm", tmp_path / "o.lcm"
    cut(drive, log, 5, 7, "LIDAR_SCAN,GROUND_TRUTH")
    w, last = lcm.EventLog(str(thin), "w", overwrite=True), None
    for ev in lcm.EventLog(str(log), "r"):
        if ev.channel == "LIDAR_SCAN":
            if last is not None and ev.timestamp - last < 950000:
                continue
            last = ev.timestamp
        w.write_event(ev.timestamp, ev.channel, ev.data)
    w.close()
    t_scan = lb.read_channel_times(thin, "LIDAR_SCAN")
    assert len(t_scan) >= 6
    i = np.searchsorted(drive["gt"][:, 0], t_scan[1])
    speed = np.hypot(*(drive["gt"][i + 1, 1:3] - drive["gt"][i, 1:3])) / ((drive["gt"][i + 1, 0] - drive["gt"][i, 0]) * 1e-6)
    assert speed > 3, "the car moves metres between sweeps"
    g = drive["gt"][np.searchsorted(drive["gt"][:, 0], t_scan[0])]
    x, y = g[1] + 3 * math.cos(-1.0), g[2] + 3 * math.sin(-1.0)
    localize(drive, thin, out, f"--initial-pose={x},{y},{g[3]},0,0,{math.degrees(g[4]) - 15}")
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    # measured: tracking at the 5th sweep (4 s; the 3rd before the 2nd and 3rd had to be
    # deskewed with a speed their matches confirm: the speed from two matches 1 s apart
    # lags an accelerating car by 2-3 m/s); the first tracking POSE 0.03 m off, the worst
    # 0.197 m (the 1 s prediction is metres off, the match pulls it in). 5 s: the target
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 5.0e6, statuses(out)
    _, et, ey = lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], drive["gt"])
    assert et[0] < 0.1 and et.max() < 0.6 and ey.max() < 1.5, (et, ey)
    assert 3 not in poses[k:, 5]


def test_no_prior_start_searches_the_map(drive, tmp_path):
    """No INITIAL_POSE, no GNSS, no IMU or CAN: the localizer finds the car by itself
    (place descriptors of the map, verified by registration and the structure test)."""
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut(drive, log, 5, 6, "LIDAR_SCAN,GROUND_TRUTH")
    p = localize(drive, log, out)
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    # measured: tracking after 0.3 s (0.2 s before sweeps had to be deskewed with a speed
    # their matches confirm), max error 0.067 m
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 1.0e6, "tracking within 1 s"
    _, et, _ = lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], drive["gt"])
    assert et.max() < 0.2, et.max()
    # with the search switched off there is no pose: STATUS says why, and every POSE says it is
    # unknown (status initializing, a covariance that is not "certain", never a zero one)
    out2 = tmp_path / "o2.lcm"
    localize(drive, log, out2, "--no-global-search")
    assert 1 not in statuses(out2)
    st = last_status_msg(out2)
    assert "no pose" in st.last_error and "INITIAL_POSE" in st.last_error
    from portobello import pose_t
    for m in [pose_t.decode(d) for ch, _, d in read_log(out2, {"POSE"})]:
        assert m.status == m.STATUS_INITIALIZING
        cov = np.array(m.covariance).reshape(6, 6)
        assert np.all(np.diag(cov)[:3] >= 1e8) and np.all(np.diag(cov)[3:] >= 9.0)


def test_lidar_outage_is_lost_by_time_then_recovers(drive, tmp_path):
    """A LiDAR outage longer than --lidar-lost-s: LOST at the limit (dead reckoning is no pose),
    tracking again within 5 s of the scans' return."""
    flog, out = tmp_path / "gap.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "lidar-gap", "--in", drive["log"], "--out", flog, "--at", "3", "--for", "5"])
    localize(drive, flog, out, "--no-gnss", "--lidar-lost-s", "2",
             "--initial-pose=%f,%f,%f,0,0,%f" % (*drive["gt"][0, 1:4], math.degrees(drive["gt"][0, 4])))
    t0 = lb.read_channel_times(flog, "IMU")[0]
    scans = lb.read_events(flog, ["LIDAR_SCAN"])
    last_before = max(lb.read_poses(out, "POSE")[:, 0][lb.read_poses(out, "POSE")[:, 0] < t0 + 3e6])
    poses = lb.read_poses(out, "POSE")
    lost = poses[(poses[:, 5] == 3)]
    assert len(lost), "LOST during the outage"
    # measured: LOST 2.0x s after the last sweep (POSE go on at 10 Hz)
    assert 1.9e6 <= lost[0, 0] - last_before <= 2.3e6, (lost[0, 0] - last_before) * 1e-6
    back = poses[poses[:, 0] >= t0 + 8e6]
    k = first_tracking(back)
    assert k is not None and back[k, 0] - (t0 + 8e6) <= 1e6, "tracking within 1 s of the return (measured 0.3 s)"
    _, et, _ = lb.errors_vs_truth(back[k:][back[k:, 5] == 1], drive["gt"])
    assert et.max() < 0.02, et.max()     # measured 0.007 m
    assert counters(last_status_msg(out)).get("lidar_outage") == 1
    assert len(scans) > 0


def test_gnss_clock_offset_is_found_reported_and_taken_out(drive, tmp_path):
    flog, out = tmp_path / "clk.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "gnss-clock", "--in", drive["log"], "--out", flog, "--seconds", "2"])
    localize(drive, flog, out)
    r = lb.score_run(drive["drive"], out)
    # measured: tracking 0.x s after the first sweep
    assert r["first_tracking_s"] <= 0.6, r     # measured 0.2 s
    assert r["lost_after_tracking"] == 0 and r["t_p99"] < 0.03, r     # measured 0.009 m
    st = last_status_msg(out)
    assert counters(st).get("gnss_clock_offset", 0) >= 1
    from portobello import status_t
    msgs = [status_t.decode(d) for ch, _, d in read_log(out, {"STATUS"})]
    import re
    said = [float(m.group(1)) for m in (re.search(r"GNSS_FIX: the receiver's clock is ([+-][0-9.]+) s off", x.last_error)
                                        for x in msgs) if m]
    # measured: +1.90 s (the 2 s offset less the fix's own ~0.1 s delivery delay in the log)
    assert said and 1.7 <= said[0] <= 2.1, said


def test_clock_step_back_carries_the_pose_over(drive, tmp_path):
    """The sensors' clock steps back 10 s (NTP, GNSS time sync) while the car drives on: the
    state moves to the new clock (no restart, no search), POSE_PREDICTED goes on at the IMU
    rate and the track continues."""
    flog, out = tmp_path / "step.lcm", tmp_path / "o.lcm"
    run([sys.executable, FAULT, "time-step", "--in", drive["log"], "--out", flog, "--at", "5", "--seconds", "10"])
    localize(drive, flog, out, "--no-gnss",
             "--initial-pose=%f,%f,%f,0,0,%f" % (*drive["gt"][0, 1:4], math.degrees(drive["gt"][0, 4])))
    c = counters(last_status_msg(out))
    assert c.get("time_jump") == 1, c
    poses, pred = lb.read_poses(out, "POSE"), lb.read_poses(out, "POSE_PREDICTED")
    k = int(np.nonzero(np.diff(poses[:, 0]) < -5e6)[0][0]) + 1          # the first POSE on the new clock
    after = poses[k:]
    # measured: every POSE after the step tracking (degraded only between the step and the
    # next accepted match); never initializing or lost
    assert set(after[:, 5].astype(int)) <= {1, 2} and np.sum(after[:, 5] != 1) <= 2, after[:20, 5]
    # the truth on the new clock is the drive's truth 10 s later
    gt_new = drive["gt"].copy()
    gt_new[:, 0] -= 10e6
    _, et, _ = lb.errors_vs_truth(after[after[:, 5] == 1], gt_new)
    assert len(et) > 30 and et.max() < 0.03, et.max()       # measured: max 0.009 m over 69 POSE
    # POSE_PREDICTED at every IMU sample across the step: measured 1 missing (2378 of 2379;
    # the samples that showed the step before it was taken are dropped as out of order)
    imu = lb.read_channel_times(flog, "IMU")
    k_imu = int(np.nonzero(np.diff(imu) < -5e6)[0][0]) + 1
    n_imu = int(np.sum(imu[:k_imu] >= pred[0, 0])) + len(imu) - k_imu    # IMU samples since the first pose
    assert n_imu - 3 <= len(pred) <= n_imu, (len(pred), n_imu)
    jump = np.nonzero(np.diff(pred[:, 0]) < -5e6)[0]
    # measured: the predicted times step back 9.990 s (10 s less the 2 samples dropped)
    assert len(jump) == 1 and 9.97e6 <= pred[jump[0], 0] - pred[jump[0] + 1, 0] <= 10.0e6


def test_frame_mismatch_is_an_error_naming_both(drive, tmp_path):
    """Scans imported for one vehicle (or in the LiDAR's own frame) run with another vehicle file."""
    from portobello import lidar_scan_t
    src = [(ts, d) for ch, ts, d in read_log(drive["log"], {"LIDAR_SCAN"})][:3]
    import lcm
    log = tmp_path / "imported.lcm"
    w = lcm.EventLog(str(log), "w", overwrite=True)
    for ts, d in src:
        s = lidar_scan_t.decode(d)
        s.sensor = "lidar:imported"
        w.write_event(ts, "LIDAR_SCAN", s.encode())
    w.close()
    out = tmp_path / "o.lcm"
    p = run([BIN / "localizer", "--site", drive["site"], "--replay", log, "--out", out], check=False, timeout=60)
    assert p.returncode == 1
    assert "lidar:imported" in p.stderr and "prius2017" in p.stderr
    st = last_status_msg(out)
    assert st.state == st.STATE_ERROR and "prius2017" in st.last_error


@pytest.fixture(scope="module")
def reverse_drive(tmp_path_factory):
    """simdrive --reverse 8: the car backs 8 m at its first stop (about 15 s in); Toyota
    speeds are magnitudes, the gear is in GEAR_PACKET. Kept: 12-28 s, around the manoeuvre,
    with GEAR_PACKET removed before the CAN decoding (a car whose DBC has no gear)."""
    d = tmp_path_factory.mktemp("reverse")
    run([BIN / "simdrive", "--out", d, "--seed", "5", "--duration", "30", "--reverse", "8", "--quiet"])
    lb.add_speed_without_gear(d / "drive.lcm", d / "merged.lcm", d)
    run([sys.executable, FAULT, "cut", "--in", d / "merged.lcm", "--out", d / "input.lcm", "--at", "12", "--for", "16"])
    gt, fwd = lb.forward_speed(d / "drive.lcm")
    site = d / "site"
    site.mkdir()
    write_cropped_map(gt, site / "map.pcd")
    return {"dir": d, "gt": gt, "fwd": fwd, "site": site, "input": d / "input.lcm"}


@pytest.mark.parametrize("mode", ["imu_can_no_gear", "lidar_only"])
def test_reversing_keeps_tracking(reverse_drive, tmp_path, mode):
    """Backing 8 m: with IMU and an unsigned CAN speed the direction comes from the IMU at the
    departure; LiDAR alone takes it from the matches. Tracking all along, no LOST."""
    r = reverse_drive
    gt, inp = r["gt"], r["input"]
    t_first = lb.read_channel_times(inp, "LIDAR_SCAN")[0]
    g = gt[np.searchsorted(gt[:, 0], t_first)]
    out = tmp_path / "o.lcm"
    extra = ["--no-imu", "--no-speed"] if mode == "lidar_only" else []
    localize(r, inp, out, "--no-gnss", *extra, "--initial-pose=%f,%f,%f,0,0,%f" % (*g[1:4], math.degrees(g[4])),
             site=r["site"])
    poses = lb.read_poses(out, "POSE")
    t_rev = gt[r["fwd"] < -0.3, 0]
    assert t_rev[-1] - t_rev[0] > 4e6                           # the car did back (measured 5.1 s)
    k = first_tracking(poses)
    assert k is not None and poses[k, 0] < t_rev[0] - 1e6        # tracking before it backs
    during = poses[(poses[:, 0] >= t_rev[0]) & (poses[:, 0] <= t_rev[-1])]
    assert len(during) > 40 and np.all(during[:, 5] == 1), during[:, 5]
    assert not np.any(poses[k:, 5] == 3)
    _, et, ey = lb.errors_vs_truth(during, gt)
    # measured while backing (51 POSE): IMU + CAN without gear p99 0.074 m (the first
    # 0.2 s of the departure, before the IMU has told the direction), LiDAR-only p99
    # 0.009 m; yaw p99 0.003-0.004 degrees in both
    bound = 0.2 if mode == "imu_can_no_gear" else 0.026
    assert np.percentile(et, 99) < bound and np.percentile(ey, 99) < 0.011, (np.percentile(et, 99), np.percentile(ey, 99))


def street_drive(d, depth, seed, duration, street=None, drop=None, tunnel=False):
    """The street of trees (tree_street.py) with canopies porous to depth (0: solid) in d:
    the map from the mapping lap at the true poses (as make builds the default map) in
    site_full, a drive (seed, duration s), and site with the map cropped to the drive.
    street: a folder where street_map already wrote this depth's site/ and full.pcd.
    drop: the classes left out of the default site (tree_street.py; default: its buildings).
    tunnel: with tree_street.py's tunnel."""
    import tree_street
    site, full = d / "site", d / "site_full"
    if street is None:
        tree_street.street_map(site, d / "full.pcd", depth, d / "mapping",
                               tree_street.TREES if drop is None else drop, tunnel)
    else:
        shutil.copytree(street / "site", site)
        (d / "full.pcd").symlink_to(street / "full.pcd")
    run([BIN / "simdrive", "--seed", str(seed), "--duration", str(duration), "--site", site, "--foliage-depth",
         str(depth), "--quiet", "--out", d])
    gt = lb.read_poses(d / "drive.lcm", "GROUND_TRUTH")
    shutil.copytree(site, full)
    (full / "map.pcd").symlink_to(d / "full.pcd")
    lb.crop_map(d / "full.pcd", gt, site / "map.pcd", 70)
    return {"log": d / "drive.lcm", "gt": gt, "site": site, "site_full": full, "dir": d}


@pytest.fixture(scope="module")
def tree_street(tmp_path_factory):
    """The default site without its buildings: trunks, solid canopies, poles and parked
    cars, which differ between the mapping day and the drive day; a 12 s drive (seed 5)."""
    return street_drive(tmp_path_factory.mktemp("trees"), 0, 5, 12)


def test_parked_cars_that_came_after_the_map_do_not_lose_a_right_pose(tree_street, tmp_path):
    """A street without buildings, whose parked cars changed since the map: at the right
    pose the structure fits under the 55% threshold on some sweeps, but far better than
    1-2 m away (the sharp-peak rule). LiDAR alone from the true start: tracking all along."""
    t = tree_street
    g = t["gt"][0]
    out = tmp_path / "o.lcm"
    localize(t, t["log"], out, "--no-gnss", "--no-imu", "--no-speed",
             "--initial-pose=%f,%f,%f,0,0,%f" % (*g[1:4], math.degrees(g[4])), site=t["site"])
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    assert k is not None and k <= 2, poses[:5, 5]
    # without the rule this fails: those sweeps are rejected (DEGRADED; ten in a row, LOST)
    assert np.all(poses[k:, 5] == 1), poses[k:, 5]
    c = counters(last_status_msg(out))
    assert c.get("match_structure_peak", 0) >= 1, c       # measured 10 of 118 sweeps: the case arose
    _, et, ey = lb.errors_vs_truth(poses[k:], t["gt"])
    # measured: p99 0.074 m, yaw p99 0.073 degrees
    assert np.percentile(et, 99) < 0.22 and np.percentile(ey, 99) < 0.22, (np.percentile(et, 99), np.percentile(ey, 99))


@pytest.fixture(scope="module")
def bare_street(tmp_path_factory):
    """The default site without its buildings and trees: poles, and parked cars that differ
    between the mapping day and the drive day; an 18 s drive (seed 5) that slows to a stop
    at a crosswalk from 12 s."""
    import tree_street
    return street_drive(tmp_path_factory.mktemp("bare"), 0, 5, 18, drop=tree_street.BARE)


@pytest.mark.parametrize("at,fused", [(11.5, False), (9.5, True)])
def test_global_search_takes_no_place_on_the_ground_alone(bare_street, tmp_path, at, fused):
    """No prior at all, on the bare street (whole map), the car slowing to a stop where little
    stands above the road: the structure test cannot judge (fewer than 300 returns 0.7 m over
    it). The global search took a place 540 m off there on the ground alone, which fits
    anywhere, and such sweeps verified it (both cuts). Now a place found without a prior is
    neither taken nor verified on a sweep whose structure cannot be judged: no place is taken
    in these cuts (measured: none tracking within their 6 s), and none at a wrong place."""
    t = bare_street
    d = t["dir"] / "fused"
    src = lb.make_drive(d, 5, "normal", 16, (), t["site_full"]) if fused else t["log"]
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut({"log": src}, log, at, 6, "LIDAR_SCAN,IMU,VEHICLE_SPEED,GROUND_TRUTH" if fused else "LIDAR_SCAN,GROUND_TRUTH")
    localize(t, log, out, "--no-gnss", site=t["site_full"])
    poses = lb.read_poses(out, "POSE")
    trk = poses[poses[:, 5] == 1]
    _, et, _ = lb.errors_vs_truth(trk, t["gt"])
    assert not len(et) or et.max() < 0.2, ("tracking a wrong place", et.max())
    c = counters(last_status_msg(out))
    assert c.get("global_no_structure", 0) + c.get("match_structure_unjudged", 0) >= 1, c   # the case arose


@pytest.mark.parametrize("fused", [False, True])
def test_parked_cars_that_changed_on_a_bare_street_do_not_make_a_right_pose_lost(bare_street, tmp_path, fused):
    """The bare street's corner 5-7 s in, where the drive day's parked cars are most of what
    stands: at the right pose the structure fits 10-27 %, 1-2 m away 6-19 % (no sharp peak),
    and ten such sweeps in a row made a car tracked to 5 cm LOST. No place within 20 m fits
    better: the scene changed, not the pose, which is held (DEGRADED). From the true start;
    test_kidnapped_car_is_reported_lost_and_relocalized keeps a wrong pose from being held."""
    t = bare_street
    g = t["gt"][0]
    out = tmp_path / "o.lcm"
    extra = () if fused else ("--no-imu", "--no-speed")
    localize(t, t["log"], out, "--no-gnss", *extra, "--initial-pose=%f,%f,%f,0,0,%f" % (*g[1:4], math.degrees(g[4])),
             site=t["site"])
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    assert k is not None and k <= 2, poses[:5, 5]
    # without the hold: LOST on 12-13 POSE of this corner (docs/history/localizer.md)
    assert not np.any(poses[k:, 5] == 3), np.nonzero(poses[k:, 5] == 3)
    c = counters(last_status_msg(out))
    assert c.get("match_structure_held", 0) >= 1, c       # the case arose
    _, et, ey = lb.errors_vs_truth(poses[k:], t["gt"])
    # measured (7 Dec), whole drive from the first tracking POSE: LiDAR alone p99 0.129 m, yaw
    # p99 0.87 degrees (the ten rejected sweeps before the hold, dead-reckoned through the
    # corner's turn: up to 1.28 degrees, DEGRADED); IMU + CAN p99 0.102 m, yaw p99 0.066 degrees
    bt, by = (0.3, 0.2) if fused else (0.39, 2.6)
    assert np.percentile(et, 99) < bt and np.percentile(ey, 99) < by, (np.percentile(et, 99), np.percentile(ey, 99))


@pytest.fixture(scope="module")
def tunnel_street(tmp_path_factory):
    """tree_street.py's tunnel: 272 m of the default site's south straight between walls 6 m
    high, nothing else beside the road (the rest of the site as it is); a 36 s drive (seed 5)
    that enters it at 18 s and stops inside it from 29 s."""
    return street_drive(tmp_path_factory.mktemp("tunnel"), 0, 5, 36, drop=(), tunnel=True)


@pytest.mark.parametrize("fused", [False, True])
def test_a_tunnel_is_not_tracked_as_if_the_way_along_it_were_known(tunnel_street, tmp_path, fused):
    """In a tunnel the walls and the road fix every direction but the one along them, and the
    match's covariance still said centimetres there: LiDAR alone the car was TRACKING 59 m off
    the truth with a 3 cm sd (2,445 sd), with IMU and CAN 0.38 m off (67 sd). A match one of
    whose registrations started 2 m either way along that direction does not come back
    (match_degenerate, three sweeps in a row) is not used along it; LiDAR alone the motion
    carries the position there and its uncertainty grows (DEGRADED over 0.3 m sd, LOST over
    3 m: relocalised where the walls end); with CAN the speed does. From the true start."""
    t = tunnel_street
    d = t["dir"] / "fused"
    src = lb.make_drive(d, 5, "normal", 36, (), t["site_full"]) if fused else t["log"]
    g = t["gt"][0]
    out = tmp_path / "o.lcm"
    extra = () if fused else ("--no-imu", "--no-speed")
    localize(t, src, out, "--no-gnss", *extra, "--initial-pose=%f,%f,%f,0,0,%f" % (*g[1:4], math.degrees(g[4])),
             site=t["site_full"])
    c = counters(last_status_msg(out))
    assert c.get("match_degenerate", 0) >= 10, c       # the case arose (measured 106-108 sweeps)
    et, zt = lb.sigmas_off(out, t["gt"], 1)
    ed, zd = lb.sigmas_off(out, t["gt"], 2)
    lost = int(np.sum(lb.read_poses(out, "POSE")[:, 5] == 3))
    # an honest covariance: about 1 % of TRACKING POSE beyond 3 sd (2 dof). Measured (7 Dec
    # 2026) with the map-relative 3 cm (pose_bias_sigma_m): LiDAR alone 1 of 255, at most 3.0 sd;
    # fused none of 357, at most 2.1 sd (before it: 8.9 and 13-18 sd, 14-40 % beyond 3 sd)
    beyond = float(np.mean(zt > 3))
    if fused:
        # measured: 357 POSE TRACKING, none DEGRADED, max 0.062 m (0.38 m over a longer drive before)
        assert len(ed) <= 5 and et.max() < 0.18, (len(ed), et.max())
        assert beyond <= 0.015 and zt.max() < 6.5, (beyond, zt.max())
    else:
        # measured: TRACKING at most 0.126 m off (59 m before; 2,445 sd of its own covariance);
        # DEGRADED on 15 POSE (1.4 sd at most), then LOST on 88 (the position along the tunnel
        # known to no better than 3 m: the car stopped inside)
        assert len(ed) + lost > 50 and et.max() < 0.38, (len(ed), lost, et.max())
        assert beyond <= 0.015 and max(zt.max(), zd.max(initial=0)) < 9, (beyond, zt.max(), zd.max(initial=0))


@pytest.fixture(scope="module")
def porous_map(tmp_path_factory):
    """The street of trees with porous canopies (a beam stops at a random depth inside a
    canopy, anew every sweep, as in real foliage): its site files and whole map, made once
    for the two drives below."""
    import tree_street
    d = tmp_path_factory.mktemp("porous_map")
    tree_street.street_map(d / "site", d / "full.pcd", 0.7, d / "mapping")
    return d


@pytest.fixture(scope="module")
def porous_street(tmp_path_factory, porous_map):
    """The porous street; a 31 s drive (seed 8)."""
    return street_drive(tmp_path_factory.mktemp("porous"), 0.7, 8, 31, porous_map)


@pytest.mark.parametrize("seed,at,fused", [(7, 21.5, False), (6, 24.0, True)])
def test_global_search_takes_no_wrong_place_on_a_street_of_trees(porous_street, tmp_path, seed, at, fused):
    """No prior at all, on the porous street (whole map). Seed 7, LiDAR alone: the global
    search proposed a place 192 m off where the trees repeat; a search around its
    prediction made a verifying sweep fit there, it was taken and tracked, then LOST (39
    POSE). Now sweeps at 10 Hz verify such a place only where its motion puts them.
    Seed 6, with IMU and CAN speed: the second sweep's best place fitted 0.69 of the
    structure 283 m along the street (the truth fits 0.97 but was not among the places
    searched), and the known speed verified it there. A place that fits less than 0.8 is
    now taken only when no surer one came within 1 s of sweeps."""
    t = porous_street
    d = t["dir"] / f"seed{seed}"
    # porous canopies; the LiDAR from 1 s before the cut (its sweeps are the whole drive's)
    world = ("--foliage-depth", "0.7", "--lidar-from", str(at - 1))
    src = lb.make_drive(d, seed, "normal", int(at + 7), world, t["site_full"]) if fused else d / "drive.lcm"
    if not fused and not src.exists():
        run([BIN / "simdrive", "--seed", str(seed), "--duration", str(int(at + 6.5)), "--site", t["site_full"],
             *world, "--quiet", "--out", d])
    gt = lb.read_poses(d / "drive.lcm", "GROUND_TRUTH")
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut({"log": src}, log, at, 6, "LIDAR_SCAN,IMU,VEHICLE_SPEED,GROUND_TRUTH" if fused else "LIDAR_SCAN,GROUND_TRUTH")
    localize(t, log, out, "--no-gnss", site=t["site_full"])
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 5.0e6, "tracking within 5 s"
    _, et, _ = lb.errors_vs_truth(poses[k:][poses[k:, 5] != 0], gt)
    # measured (6 Dec 2026): seed 7 tracking at 0.4 s, worst error 0.092 m (before: 198 m, then
    # LOST); seed 6 tracking at 0.2 s, worst 0.014 m (the same cut of bench-localizer-trees'
    # drive 6; before: 283 m, tracked there)
    assert et.max() < 0.2, et.max()
    assert 3 not in poses[k:, 5]


def lidar_only_prior_start(t, tmp_path, at, offset, site=None):
    """LiDAR alone, 6 s of drive t cut at `at` s, a prior `offset` (dx, dy, dz in m, dyaw in
    degrees) from the truth at its first sweep: the POSE rows, the index of the first tracking
    one (None: none), the errors of the tracking POSE from there on, and the output log."""
    log, out = tmp_path / "cut.lcm", tmp_path / "o.lcm"
    cut(t, log, at, 6, "LIDAR_SCAN,GROUND_TRUTH")
    g = t["gt"][np.searchsorted(t["gt"][:, 0], lb.read_channel_times(log, "LIDAR_SCAN")[0])]
    dx, dy, dz, dyaw = offset
    localize(t, log, out, f"--initial-pose={g[1] + dx},{g[2] + dy},{g[3] + dz},0,0,{math.degrees(g[4]) + dyaw}",
             site=site)
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    et = None if k is None else lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], t["gt"])[1]
    return poses, k, et, out


@pytest.mark.parametrize("at", [24.5, 27.0])
def test_moving_lidar_only_start_settles_on_a_street_of_trees(porous_street, tmp_path, at):
    """LiDAR alone, the car at 9 m/s, a prior 2.9 m and 3 degrees off. The first speed comes
    from two matches of unskewed sweeps and was 2-3 m/s off; deskewed with it, the next
    matches ran tenths of a metre along the road (measured, worst tracking error without
    smoothing the deskewing speed after a start: 0.409 m at 24.5 s, 0.211 m at 27.0 s;
    with it: 0.135 and 0.074 m; 6 Dec 2026, the prediction also the match's prior: 0.139 and
    0.066 m)."""
    poses, k, et, _ = lidar_only_prior_start(porous_street, tmp_path, at, (2.436, 1.54, -0.26, 3.178))
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 1.0e6, "tracking within 1 s"
    # the start judged as bench-localizer-trees judges it: every tracking POSE within 0.2 m
    assert et.max() < 0.2, et.max()
    assert 3 not in poses[k:, 5]


@pytest.fixture(scope="module")
def porous_street_seed5(tmp_path_factory, porous_map):
    """The porous street, bench-localizer-trees' drive (seed 5), its first 14 s."""
    return street_drive(tmp_path_factory.mktemp("porous5"), 0.7, 5, 14, porous_map)


@pytest.mark.parametrize("offset", [(0.12, -0.584, 0.793, -5.069), (-1.918, -1.298, -0.465, -9.918)])
def test_moving_lidar_only_start_verifies_deskewed_sweeps(porous_street_seed5, tmp_path, offset):
    """LiDAR alone, the car at 8.6 m/s, priors that bench-localizer-trees draws (its starts 22
    and 12 at 7.5 s). The first two matches are of sweeps that could not be deskewed (the
    speed is not known yet), and the speed from them was 6 m/s off; verified by them and a
    third deskewed with that speed, the track began 0.13 and 0.27 m behind the car (measured
    before sweeps had to be deskewed with a speed their match confirms; 0.44 and 0.32 m on
    the bench's 40 s drive). Measured since (6 Dec 2026): tracking after 0.3 s, the first
    tracking POSE 0.026 m off, the worst 0.071 m, from both priors."""
    poses, k, et, out = lidar_only_prior_start(porous_street_seed5, tmp_path, 7.5, offset)
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 2.0e6, "tracking within 2 s"
    assert et[0] < 0.08 and et.max() < 0.2, (et[0], et.max())
    assert counters(last_status_msg(out)).get("verify_deskew", 0) >= 1   # the rule engaged
    assert 3 not in poses[k:, 5]


def test_moving_lidar_only_start_keeps_the_stop_near_the_prediction_on_a_tie(porous_street_seed5, tmp_path):
    """LiDAR alone, the car at 9 m/s, the prior bench-localizer-trees draws first (its cut at
    3.0 s). At 6.8 s into the drive a sweep's fine run from the prediction stopped 0.07 m from
    the truth and the coarse-to-fine run 0.29 m off, 0.29 m apart (within min_corr, so not
    two minima by that test), and the second won by 1,915 inliers to 1,913: the track passed
    0.2 m for two sweeps (0.277 m). A stop beyond 3 sigma of the prediction now pays the
    margin whether or not it lies within min_corr of the other."""
    t = porous_street_seed5
    # the whole street's map, as the bench's (the map cropped to these 14 s: 0.111 m either way)
    poses, k, et, _ = lidar_only_prior_start(t, tmp_path, 3.0, (-0.642, 2.724, 0.206, 8.326), site=t["site_full"])
    assert k is not None and (poses[k, 0] - poses[0, 0]) <= 1.0e6, "tracking within 1 s"
    assert et.max() < 0.2, et.max()
    assert 3 not in poses[k:, 5]


def test_prior_for_a_moving_car_is_searched_where_the_car_may_be_by_now(porous_street_seed5, tmp_path):
    """An INITIAL_POSE 2 m off, given while the car drives at 8.6 m/s, and the LiDAR's first
    sweep 1.5 s later (it came up late, or its first sweeps were dropped): by then the car is
    13 m past the prior's 3 m disc. The prior's tries after its time search along the car's
    axis as far as it may have moved. Before, the disc stayed where the prior was given, and
    no POSE of the 4.5 s of sweeps was tracking (on bench-localizer-trees' own site: tracking
    3.8 s after the first sweep, the tries there fitting 3-9% of the structure). Measured
    since (6 Dec 2026): tracking 0.4 s after the first sweep, its first tracking POSE 0.046 m
    off, the worst 0.075 m."""
    t = porous_street_seed5
    log, prior, late = tmp_path / "cut.lcm", tmp_path / "prior.lcm", tmp_path / "late.lcm"
    out = tmp_path / "o.lcm"
    cut(t, log, 7.5, 6, "LIDAR_SCAN,GROUND_TRUTH")
    run([sys.executable, FAULT, "jump", "--in", log, "--out", prior, "--at", "0.05", "--metres", "2"])
    run([sys.executable, FAULT, "lidar-gap", "--in", prior, "--out", late, "--at", "0", "--for", "1.5"])
    t_prior = lb.read_events(late, ["INITIAL_POSE"])[0][0]
    t_scan = lb.read_channel_times(late, "LIDAR_SCAN")[0]
    assert t_scan - t_prior >= 1.4e6
    localize(t, late, out)
    poses = lb.read_poses(out, "POSE")
    k = first_tracking(poses)
    assert k is not None and poses[k, 0] - t_scan <= 1.0e6, "tracking within 1 s of the first sweep"
    _, et, _ = lb.errors_vs_truth(poses[k:][poses[k:, 5] == 1], t["gt"])
    assert et[0] < 0.15 and et.max() < 0.2, (et[0], et.max())
    assert 3 not in poses[k:, 5]


# ---------------------------------------------------------------- real data (make test-real)

@pytest.mark.real
def test_real_mulran_reference_follows_the_scans_not_the_slam(mulran_reference):
    """reference.py on MulRan Riverside02 (one thread, the same file every build). Measured 6 Dec
    2026: keyframes 23-40 move at 13.2-14.3 m/s, where the scans have one clear minimum (a pair
    aligned from starts every 1.5 m: 0.50-0.56 of the points within 0.3 m there, 0.2-0.36
    elsewhere) and the SLAM poses say 2-6 m/s; before constant velocity came first the
    reference moved at 0.7-5 m/s at 17-23 and reversed at 75-80 with the SLAM's backward steps
    (14 keyframes over 5 m/s^2, then 7: 18-22 where the scans take over, and 88, 93 where they
    said the car all but stopped for 6 s). That was a bridge of about 200 m (keyframes 88-96,
    up to 1.6 s apart), where every start stays where it began and a shorter step fits more
    points only because more of the scan lies where the previous ones looked: a step of 0.6 m
    fitted 0.60 of the points against 0.50 at 12.2 m after 12 m/s. Since 7 Dec a start away
    from the constant-velocity motion wins only where starts 2 m either way come back to it:
    the bridge is crossed at 11.8-12.4 m/s, its steps reported open (held by constant
    velocity), and only 18-22 flagged. The first 22 steps are open (starts 1 m or more apart
    fit alike), so keyframes 0-22 are flagged with them; held-out skip-3 residual median 0.036
    m, p90 0.111 m (0.038 / 0.139 m before)."""
    rep = mulran_reference["report"]
    P = np.loadtxt(mulran_reference["poses"])[:, [3, 7]]
    t = np.loadtxt(MULRAN / "times.txt")[:len(P)]
    speed = np.linalg.norm(np.diff(P, axis=0), axis=1) / np.diff(t)
    assert np.all((speed[23:40] > 12.0) & (speed[23:40] < 15.5)), speed[23:40]
    # the bridge (steps into keyframes 89-96) at the speed before and after it (12.2, 11.7 m/s)
    assert np.all((speed[88:96] > 11.0) & (speed[88:96] < 13.5)), speed[88:96]
    assert set(range(89, 96)) <= set(rep["open_steps_refined"]), rep["open_steps_refined"]
    # no acceleration a car cannot make outside the start
    assert [k for k in rep["kinematics_keyframes_refined"] if k > 22] == [], rep
    assert set(range(18)) <= set(rep["implausible_keyframes_refined"]), rep["implausible_keyframes_refined"]
    assert rep["heldout_skip3_resid_m_median"] <= 0.1 and rep["heldout_skip3_resid_m_p90"] <= 0.33, rep


def test_reference_flags_the_keyframes_before_the_scans_fix_a_step():
    """reference.py: open steps from the first on carry a speed no scan measured, so their
    keyframes are flagged; open steps later (held at a measured speed) are not."""
    assert reference.unfixed_start([1, 2, 3, 7], 10) == [0, 1, 2, 3]
    assert reference.unfixed_start([2, 3], 10) == []
    assert reference.unfixed_start([], 10) == []
    assert reference.unfixed_start([1, 2, 3], 4) == [0, 1, 2, 3]


@pytest.mark.real
def test_real_mulran_tracking_against_refined_reference(mulran_reference, tmp_path):
    """Registration from tracking starts (5 cm, as a filter's prediction) on the 83 odd MulRan
    keyframes, the map from the even ones at the refined reference (reference.py, one thread:
    the same file every build). Measured 26 Nov 2026: 98.8% within 0.2 m, median 0.028 m, p99
    0.196 m. Before the coarse retry took the guess as a prior: 92.8%, p99 1.21 m (starts slid
    metres along the road to minima with a handful more inliers).
    27 Nov, since a stopped fine run is finished before it is compared: 89.2% of all 83, every
    miss (keyframes 7-21, 89, 91: 0.22-0.57 m) within 3 keyframes of one the reference itself
    judges implausible (reference.py: over 5 m/s^2 between keyframes, at 10, 18-23, 76-81, 88,
    93), where small_gicp GICP and PCL NDT from the same starts disagree with it too
    (docs/history/localizer.md, "Finished minima"). Judged against the reference where it is
    plausible (61 keyframes): 100%, median 0.025 m, p99 0.095 m; and a miss anywhere else
    fails. 6 Dec, the reference built at constant velocity first (its flags: 0-22, before the
    scans fix a step, 88 and 93): 94.0 % of all 83, the misses at keyframes 3, 7, 17, 19 and
    23 (0.20-0.35 m); where plausible (64 keyframes) 100 %, median 0.024 m, p99 0.090 m."""
    common = ["--scans", MULRAN / "Scans", "--poses", mulran_reference["poses"], "--times", MULRAN / "times.txt",
              "--quiet"]
    run([BIN / "import-scans", *common, "--every", "2", "--map-out", tmp_path / "map.pcd", "--voxel", "0.15",
         "--out", tmp_path / "even.lcm"])
    run([BIN / "import-scans", *common, "--out", tmp_path / "all.lcm"])
    p = run([BIN / "bench-localizer", "--log", tmp_path / "all.lcm", "--map", tmp_path / "map.pcd", "--odd",
             "--every", "1", "--converge", "0.2", "--baseline-every", "0", "--seed", "1", "--verbose",
             "--json", tmp_path / "r.json"])
    track = json.loads((tmp_path / "r.json").read_text())["ours_track"]
    assert track["n"] == 83
    err = {int(m[1]): float(m[2]) for m in re.finditer(r"^scan (\d+) tracking: err ([\d.]+) m", p.stdout, re.M)}
    assert len(err) == 83, p.stdout[-500:]
    implausible = mulran_reference["implausible"]
    doubtful = {k for k, ok in zip(err, reference.plausible(err, implausible)) if not ok}
    plausible = np.array([e for k, e in err.items() if k not in doubtful])
    assert len(plausible) >= 55, (len(plausible), implausible)     # 64 measured
    # bounds near three times the measured misses and errors
    assert np.mean(plausible <= 0.2) >= 0.96, np.sort(plausible)[-5:]
    assert np.median(plausible) <= 0.07 and np.percentile(plausible, 99) <= 0.27, np.sort(plausible)[-5:]
    misses = sorted(k for k, e in err.items() if e > 0.2)
    assert set(misses) <= doubtful, (misses, implausible)
    assert track["t_median"] <= 0.08, track


def mulran_start(gt, cut_log, out, site, *prior):
    """The localizer on a cut of MulRan keyframes as bench-localizer-real runs it (LiDAR alone,
    the mast vehicle file), from prior (none: a global search): bench_starts' judgement."""
    localize(None, cut_log, out, "--vehicle", ROOT / "vehicles" / "lidar_mast.yaml", "--no-gnss", "--no-imu",
             "--no-speed", *prior, site=site)
    r = bs.judge(gt, out)
    print(f"{cut_log.name}, {prior[0] if prior else 'no prior'}: tracking {r['tracking_s']} s after the first "
          f"keyframe, worst {r['max_m']} m")
    return r


def mulran_no_prior_starts(mulran_reference, tmp_path, ats, log="odd", plausible=True):
    """The `log` MulRan keyframes (odd or even) in the site of the others, cut 8 s from each
    of ATS s into the log (where the reference is plausible, unless `plausible` is False),
    each started with no prior: bench_starts' judgement of each."""
    times = (MULRAN / "times.txt").read_text().splitlines()
    site, kf_log = keyframe_site.split(MULRAN / "Scans", mulran_reference["poses"], MULRAN / "times.txt",
                                       ROOT / "vehicles" / "lidar_mast.yaml", tmp_path, log)
    gt = lb.read_poses(kf_log, "GROUND_TRUTH")
    flagged = [float(times[k]) for k in mulran_reference["implausible"]]
    runs = []
    for at in ats:
        c, out = tmp_path / f"cut_{at:g}.lcm", tmp_path / f"out_{at:g}.lcm"
        bs.cut(kf_log, c, at, 8.0, "LIDAR_SCAN,GROUND_TRUTH")
        assert real_starts.reference_plausible(lb.read_poses(c, "GROUND_TRUTH"), flagged) == plausible, at
        runs.append(mulran_start(gt, c, out, site))
    return runs


@pytest.mark.real
def test_real_mulran_no_prior_starts_on_a_tree_lined_road(mulran_reference, tmp_path):
    """The whole localizer on the odd MulRan keyframes (LiDAR alone, keyframes about 1 s apart)
    with no prior at all, in the site of the even ones, as bench-localizer-real runs it: two
    8 s cuts of the straight tree-lined road (85 and 90 s into the drive, where the reference
    is plausible) must track within 5 s of their first keyframe (the issue's target), every
    tracking POSE within 0.2 m of the reference. There the true place ranked below the 8th
    of the place descriptors on some keyframes, and the 8 best fitted 32-52 % of the structure
    at places 2-93 m along the road: with 8 places verified a sweep they tracked after 5.4 and
    6.4 s; with 16, measured 28 Nov 2026: 2.8 and 1.4 s, worst error 0.07 and 0.04 m; with a
    place every metre (later that day): 1.9 and 1.4 s."""
    for r in mulran_no_prior_starts(mulran_reference, tmp_path, (85.0, 90.0)):
        assert r["tracking_s"] is not None and r["tracking_s"] <= 5.0, r["tracking_s"]
        assert r["converged"] and r["lost"] == 0, (r["max_m"], r["lost"])


@pytest.mark.real
def test_real_mulran_no_prior_start_where_the_sector_means_named_a_wrong_turn(mulran_reference, tmp_path):
    """The odd MulRan keyframes with no prior, cut 48.5 and 51.0 s into the log (reference
    plausible), as bench-localizer-real runs them. The place descriptors were compared under
    the few sector shifts that the mean height of each sector proposed; on this tree-lined
    road those means named a wrong turn at the true place (answered 106 degrees off, ranked
    303rd), no true place was verified and neither cut tracked within its 8 s. Compared
    under every shift, the true place ranks 1st and 6th (measured 6 Dec 2026: tracking 3.9
    and 2.5 s after the cut, worst 0.04 m each)."""
    for r in mulran_no_prior_starts(mulran_reference, tmp_path, (48.5, 51.0)):
        assert r["tracking_s"] is not None and r["tracking_s"] <= 5.0, r["tracking_s"]
        assert r["converged"] and r["lost"] == 0 and r["max_m"] < 0.12, (r["max_m"], r["lost"])


@pytest.mark.real
def test_real_mulran_no_prior_start_whose_true_place_the_ring_key_left_out(mulran_reference, tmp_path):
    """The even MulRan keyframes in the site of the odd ones, no prior, cut 62.5 s into the log
    as bench-localizer-real cut it on 6 Dec (the cut reaches the bridge at keyframe 88, which
    the reference flagged until 7 Dec; it was good to centimetres there). With 2,700 places
    compared in full after the ring key, the true place (the best of all in full) ranked
    4,545th by the key and was never compared: the start tracked the road 92 m away the other
    way round. With 5,400 (measured 6 Dec 2026): tracking 1.8 s after the cut, worst 0.07 m;
    the bound is the bench's 0.2 m."""
    for r in mulran_no_prior_starts(mulran_reference, tmp_path, (62.5,), log="even"):
        assert r["tracking_s"] is not None and r["tracking_s"] <= 5.0, r["tracking_s"]
        assert r["converged"] and r["lost"] == 0, (r["max_m"], r["lost"])



def test_real_starts_earliest_tracking_follows_the_verification(tmp_path):
    """bench-localizer-real's per-cut "earliest": no start tracks before the localizer's
    verify_scans-th sweep (read from localizer.h, so the figure follows the code). A log of
    sweeps at 0, 0.9, 2.3 and 5.3 s (MulRan's odd split, cut 45.0 s) gives 2.3 s for three
    sweeps; fewer sweeps than that: None."""
    import lcm
    log = lcm.EventLog(str(tmp_path / "cut.lcm"), "w", overwrite=True)
    for t in (0.0, 0.9, 2.3, 5.3):
        log.write_event(int(1e15 + t * 1e6), "LIDAR_SCAN", b"x")
        log.write_event(int(1e15 + t * 1e6 + 10), "GROUND_TRUTH", b"x")
    log.close()
    text = (ROOT / "modules" / "localizer" / "core" / "localizer.h").read_text()
    assert real_starts.verify_sweeps() == int(re.search(r"int verify_scans = (\d+);", text).group(1))
    assert real_starts.earliest_tracking_s(tmp_path / "cut.lcm", 3) == pytest.approx(2.3)
    assert real_starts.earliest_tracking_s(tmp_path / "cut.lcm", 4) == pytest.approx(5.3)
    assert real_starts.earliest_tracking_s(tmp_path / "cut.lcm", 5) is None
    # the picture of where the starts succeed and fail: one cut, a late no-prior start
    gt = np.array([[1e15 + t * 1e6, 10.0 * t, 0.0, 0.0, 0.0, 0] for t in np.arange(0, 6, 0.5)])
    late = {"converged": True, "tracking_s": 5.3, "max_m": 0.04}
    png = tmp_path / "starts.png"
    real_starts.plot_starts(png, "test", gt, [tmp_path / "cut.lcm"], [True], [2.3], 3, [late, late], [late], [1e9 + 1.0])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10000


def test_registration_bench_compares_accuracy_where_the_reference_is_plausible(tmp_path, capsys):
    """bench-localizer-real's second table: the same runs' errors on the baseline scans away
    from the keyframes reference.py flags (within 3 keyframes: the real-data test's rule).
    Four scans, a tracking start and two far starts each; scan 9 lies within 3 of flagged keyframe 10 and is left
    out, and with it the one error that made ours worse than NDT."""
    assert reference.plausible([1, 5, 9, 13, 17], [10, 20]) == [True, True, False, False, False]
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"implausible_keyframes_refined": [10]}))

    def run(errors):
        return {"n": len(errors), "errors": errors, "yaw_errors": [0.1] * len(errors)}
    ours = {"baseline_scan_index": [1, 5, 9, 33], "ndt_res": [2.0],
            "ours_track_red": run([0.02, 0.03, 0.50, 0.04]), "ndt2_track": run([0.03, 0.03, 0.10, 0.05]),
            "ours_off_red": run([0.02, 0.02, 0.03, 0.03, 0.9, 0.9, 0.04, 0.04]),
            "ndt2_off": run([0.02, 3.0, 0.03, 0.03, 0.1, 0.1, 0.04, 0.04])}
    table = {f"{m}_{s}": run(ours[f"ndt2_{s}"]["errors"]) for m in ("gicp", "vgicp") for s in ("track", "off")}
    bench_gicp.plausible_accuracy(report, ours, table, (2.0, None), ["track", "off"],
                                  {"track": "tracking", "off": "3m/15deg"}, 0.2)
    out = ours["where_reference_plausible"]
    assert (out["baseline_scans"], out["plausible_scans"]) == (4, 3)
    assert out["ours_track_red"]["n"] == 3 and out["ours_track_red"]["t_median"] == pytest.approx(0.03)
    assert out["ours_off_red"]["n"] == 6 and out["ours_off_red"]["converged"] == 1.0
    assert out["ndt2_off"]["converged"] == pytest.approx(5 / 6)
    text = capsys.readouterr().out
    assert "3 of 4 baseline scans" in text and "WORSE" not in text
    # a run without per-run errors (an older results file) gives no row, not a wrong one
    assert bench_gicp.accuracy_on({"n": 4}, [True] * 4, 0.2) is None


def test_bench_accuracy_verdict_compares_the_runs_both_converged():
    """bench_gicp's "equal or better": convergence share, then the error on the runs both
    converged. From 3 m away a baseline that fails most starts keeps them near 3 m, ours a few
    further off: a p99 over every run compared those failures, not the accuracy."""
    def run(errors):
        return {**bench_gicp.accuracy(np.asarray(errors), np.zeros(len(errors)), 0.2), "errors": errors}
    ours = run([0.03] * 85 + [4.5] * 15)
    base = run([0.06] * 30 + [3.5] * 70)
    assert ours["t_p99"] > base["t_p99"] + 0.02                # every run: the failures' tail
    p = bench_gicp.paired(ours, base, 0.2)
    assert p["n"] == 30 and p["ours_p99"] == pytest.approx(0.03) and p["base_p99"] == pytest.approx(0.06)
    assert bench_gicp.better_or_equal(ours, base, 0.2)
    assert "on the 30 both converged" in bench_gicp.accuracy_text(ours, base, 0.2)
    # a baseline that never converges has no accuracy to compare: better when ours converges
    assert bench_gicp.better_or_equal(ours, run([3.5] * 100), 0.2)
    assert "no run converged in both" in bench_gicp.accuracy_text(ours, run([3.5] * 100), 0.2)
    # less accurate where both converged, converged less often, neither converged, or the
    # runs do not pair up: not equal
    assert not bench_gicp.better_or_equal(run([0.09] * 85 + [4.5] * 15), base, 0.2)
    assert not bench_gicp.better_or_equal(run([0.03] * 20 + [4.5] * 80), base, 0.2)
    assert not bench_gicp.better_or_equal(run([4.5] * 100), run([3.5] * 100), 0.2)
    assert not bench_gicp.better_or_equal(ours, run([0.06] * 10), 0.2)


def mulran_cut(mulran_reference, tmp_path, at, plausible=True, split="even"):
    """The `split` MulRan keyframes (even: bench-localizer-real's second trial; odd: its
    first) in the site of the others, cut 8 s from AT s into the log, where the reference is
    plausible (or is not): (site, GROUND_TRUTH, cut log)."""
    times = (MULRAN / "times.txt").read_text().splitlines()
    site, log = keyframe_site.split(MULRAN / "Scans", mulran_reference["poses"], MULRAN / "times.txt",
                                    ROOT / "vehicles" / "lidar_mast.yaml", tmp_path, split)
    gt = lb.read_poses(log, "GROUND_TRUTH")
    c = tmp_path / "cut.lcm"
    bs.cut(log, c, at, 8.0, "LIDAR_SCAN,GROUND_TRUTH")
    assert real_starts.reference_plausible(lb.read_poses(c, "GROUND_TRUTH"),
                                           [float(times[k]) for k in mulran_reference["implausible"]]) == plausible
    return site, gt, c


def mulran_priors(gt, cut_log):
    """Three --initial-pose options 2-3 m and 10-15 degrees off the reference at the cut's
    first keyframe."""
    g = bs.gt_at(gt, lb.read_channel_times(cut_log, "LIDAR_SCAN")[0])
    out = []
    for along, across, dyaw in ((2.5, 0.0, 10.0), (-2.0, 1.5, -12.0), (0.5, -2.5, 15.0)):
        x = g[1] + along * math.cos(g[4]) - across * math.sin(g[4])
        y = g[2] + along * math.sin(g[4]) + across * math.cos(g[4])
        out.append(f"--initial-pose={x:.3f},{y:.3f},{g[3]:.3f},0,0,{math.degrees(g[4]) + dyaw:.3f}")
    return out


def mulran_prior_starts(site, gt, cut_log, tmp_path):
    """The localizer from each of mulran_priors, LiDAR alone: (output log, bench_starts'
    judgement) of each, every one tracking within the cut, converged, never LOST."""
    runs = []
    for k, prior in enumerate(mulran_priors(gt, cut_log)):
        out = tmp_path / f"out_{k}.lcm"
        r = mulran_start(gt, cut_log, out, site, prior)
        assert r["tracking_s"] is not None and r["converged"] and r["lost"] == 0, (k, r["tracking_s"], r["max_m"])
        runs.append((out, r))
    return runs


@pytest.mark.real
def test_real_mulran_start_in_a_turn_between_sparse_keyframes(mulran_reference, tmp_path):
    """The even MulRan keyframes in the site of the odd ones, cut 50.5 s into the drive: the
    keyframes come 0, 0.9, 3.0 and 6.2 s after the cut while the car turns by 67 degrees.
    The second fits only 49 % of its structure at the right place (55 % needed), and the
    fourth is predicted from two matches 3 s apart. Before 28 Nov 2026 the weak sweep
    dropped the candidate, and a straight prediction put the fourth 11.8 m off the road:
    no prior tracked within the cut. Now the weak sweep neither verifies nor drops the
    candidate, and the prediction follows the turn (measured: three priors 2-3 m / 10-15
    degrees off tracking at the fourth keyframe, worst 0.02 m)."""
    site, gt, c = mulran_cut(mulran_reference, tmp_path, 50.5)
    assert len(lb.read_channel_times(c, "LIDAR_SCAN")) == 4
    for out, r in mulran_prior_starts(site, gt, c, tmp_path):
        assert r["max_m"] < 0.06, r["max_m"]   # measured 0.02 m


@pytest.mark.real
def test_real_mulran_bridge_start_refuses_a_place_as_good_and_gives_up_a_prior_too_old(mulran_reference, tmp_path):
    """The odd split cut 63.5 s into its log: the bridge (which the reference crosses at
    constant velocity since 7 Dec 2026), keyframes 0, 3.1, 5.0, 5.9 and 6.8 s after the cut.
    A start's second keyframe, 3.1 s and 37 m on, its speed unknown, is searched tens of
    metres along the road, where places far apart fit alike: a match that a place more than
    5 m from it fits as well is refused (since 28 Nov 2026) and the candidate dropped. Until
    7 Dec the prior was then tried for the rest of the cut, searched at most 40 m along the
    road while the car was 60-80 m on, and none of the three priors tracked within the cut.
    A prior of unknown speed older than its seeds reach (25 m/s x the time since over 40 m)
    now gives way to the global search. Measured 7 Dec: the second and third priors track
    at the last keyframe (6.8 s), worst 0.039 m. The first still does not: its candidate
    lands 4 m back along the bridge, fits its second keyframe 38 % (held) and its third 28 %
    (dropped), and later sweeps around it fit 16 % or less; it stays INITIALIZING and says
    why, never a wrong pose (a shortfall of issue 9, docs/localizer.md)."""
    site, gt, c = mulran_cut(mulran_reference, tmp_path, 63.5, split="odd")
    first, *rest = mulran_priors(gt, c)
    for k, prior in enumerate(rest):
        out = tmp_path / f"out_{k}.lcm"
        r = mulran_start(gt, c, out, site, prior)
        assert r["tracking_s"] is not None and r["converged"] and r["lost"] == 0, (k, r["tracking_s"], r["max_m"])
        assert r["max_m"] < 0.12, r["max_m"]   # measured 0.039 m
        assert counters(last_status_msg(out)).get("match_ambiguous", 0) >= 1   # the refusal engaged
    out = tmp_path / "out_first.lcm"
    mulran_start(gt, c, out, site, first)
    assert set(statuses(out)) == {0}, statuses(out)   # unknown, published as unknown
    assert "fits the map" in last_status_msg(out).last_error


@pytest.mark.real
def test_real_mulran_verifying_sweep_after_a_long_gap_takes_the_best_fit(mulran_reference, tmp_path):
    """The split the other way round (the even MulRan keyframes in the site of the odd ones:
    bench-localizer-real's second trial). 53 s into the drive the keyframes come 0, 3.2 and
    5.1 s after the cut: a start's third sweep is predicted from two matches 3.2 s apart,
    1.6 m short along a tree-lined road that hardly fixes the pose along it, and the
    registration from there stopped in a minimum 1.58 m along the road (structure fit 0.61,
    the true pose's 0.86): the start was verified at the wrong place. Since a verifying sweep
    whose prediction is unsure by a metre or more is searched around it (28 Nov 2026), no
    prior and three priors 2-3 m / 10-15 degrees off track with every POSE within 0.2 m
    (measured: worst 0.04 m); before, every one of the four was 1.58 m off at that sweep."""
    site, gt, c = mulran_cut(mulran_reference, tmp_path, 53.0)
    starts = [[]] + [[p] for p in mulran_priors(gt, c)]
    for k, prior in enumerate(starts):
        out = tmp_path / f"out_{k}.lcm"
        r = mulran_start(gt, c, out, site, *prior)
        assert r["tracking_s"] is not None and r["converged"] and r["lost"] == 0, (prior, r["tracking_s"], r["max_m"])


@pytest.mark.real
def test_real_mulran_no_prior_start_between_places_of_the_old_grid(mulran_reference, tmp_path):
    """The even MulRan keyframes in the site of the odd ones, no prior, cut 48 and 55 s into
    the drive (reference plausible). The place descriptors were kept every 3 m of free
    ground, so a keyframe lay up to 2.1 m from the nearest, whose inner rings differ from
    the keyframe's: the true place was among the 16 best for 38 of the split's 83 keyframes,
    and neither cut tracked within its 8 s. With a place every metre, answers at least 3 m
    apart and every sweep trying the best 16 (not ranks 17-48 on later sweeps, which once
    took the road the wrong way round, 44 m off), 58 of 83 (measured 28 Nov 2026: tracking
    1.8 and 3.9 s after the cut, worst 0.02 m)."""
    for at in (48.0, 55.0):
        d = tmp_path / f"cut_{at:g}"
        d.mkdir()
        site, gt, c = mulran_cut(mulran_reference, d, at)
        out = d / "out.lcm"
        r = mulran_start(gt, c, out, site)
        assert r["tracking_s"] is not None and r["tracking_s"] <= 5.0, r["tracking_s"]
        assert r["converged"] and r["lost"] == 0 and r["max_m"] < 0.06, (r["max_m"], r["lost"])
