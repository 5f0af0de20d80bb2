"""occlusion: a short simulated drive with staged agents and OCCLUSION_TRUTH, replayed
through the module; agreement with the truth and bad input (NaN points, a lost pose,
no HEAD_POSE, agents beyond range). Cost figures are measured by `make bench-occlusion`."""
import math
import sys

import pytest

from conftest import BIN, ROOT, read_log, run

sys.path.insert(0, str(ROOT / "modules" / "occlusion" / "bench"))
from occ_agreement import agreement  # noqa: E402

FAULT = ROOT / "tools" / "log-fault" / "log_fault.py"
PY = ROOT / ".venv" / "bin" / "python"


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("occ")
    run([BIN / "simdrive", "--out", d, "--duration", "12", "--seed", "5", "--scenario", ROOT / "maps/default/scenes/occlusion_scene.yaml", "--head",
         "--quiet"])
    return d / "drive.lcm"


def replay(log, out, *extra):
    return run([BIN / "occlusion", "--replay", log, "--out", out, *extra])


def occlusions(path, channel="OCCLUSION"):
    from portobello import occlusion_t
    return [occlusion_t.decode(d) for _, _, d in read_log(path, {channel})]


def statuses(path):
    from portobello import status_t
    return [status_t.decode(d) for _, _, d in read_log(path, {"STATUS"})]


def counter(st, name):
    return dict(zip(st.counter_names, st.counter_values)).get(name, 0)


def test_help():
    p = run([BIN / "occlusion", "--help"])
    assert "OCCLUSION" in p.stdout and "--replay" in p.stdout


def occlusion_on_real_sweeps(*gaps):
    import json
    p = run([BIN / "occlusion-bench", "--real", ROOT / "tests/data/lidar_pair_hdl32", *gaps])
    return json.loads(p.stdout)


def test_real_sweeps_hide_behind_returns():
    """Two real HDL-32E sweeps (0.5 m apart) integrated in turn; samples the first sweep's
    own beams decide: 1 m behind a return (hidden) and 1 m before it (visible), 0.5-2.5 m
    above the ground. Measured 27 Nov 2026: 0 of 2,680 hidden answered visible (before a
    voxel hit this sweep counted whatever the tree said: 15); 212 of 2,680 visible answered
    hidden (7.9 %; stock OctoMap 337, 12.6 %); none unknown."""
    r = occlusion_on_real_sweeps("--ring-gap-deg", "1.333", "--col-gap-deg", "0.1667")
    ours, stock = r["ours"], r["stock"]
    vis, hid = ours["truth_visible"], ours["truth_hidden"]
    assert sum(hid) > 2000 and sum(vis) > 2000
    assert hid[0] <= 3                              # visible when truly hidden
    assert vis[1] <= 0.24 * sum(vis)                # hidden where visible
    assert vis[2] + hid[2] <= 10                    # the sensor looked there: not unknown
    agree = (vis[0] + hid[1]) / (sum(vis) + sum(hid))
    s_agree = (stock["truth_visible"][0] + stock["truth_hidden"][1]) / (sum(vis) + sum(hid))
    assert agree > s_agree


def test_agrees_with_truth(drive, tmp_path):
    out = tmp_path / "occ.lcm"
    replay(drive, out, "--pose-channel", "GROUND_TRUTH")
    occ = occlusions(out)
    truth = occlusions(drive, "OCCLUSION_TRUTH")
    assert len(occ) == len(truth) == 120          # one per sweep, none lost
    a = agreement(drive, out)
    assert a["samples"] > 5000
    # measured on this drive (seed 5, 12 s from rest, so the LiDAR's blind zone around the
    # car is unknown at first; the site with its relief): agreement 0.954 (error 0.046),
    # visible when truly hidden 7 of 14,404 samples (0.049 % of all, 0.35 % of the 1,995
    # hidden), truth changes followed within one sweep 421 of 460 (0.915, error 0.085);
    # bounds at 3x the measured errors (visible when hidden: kept at its earlier, tighter
    # bound, 0.085 %)
    assert a["agreement"] >= 0.862
    assert a["visible_when_hidden_of_all"] <= 0.00085
    assert a["state_changes"] > 200
    assert a["changes_within_one_sweep"] >= 0.746
    assert a["confusion"]["truth_hidden"]["module_hidden"] > 0     # it does see occluders
    # replaying again gives the same bytes
    out2 = tmp_path / "occ2.lcm"
    replay(drive, out2, "--pose-channel", "GROUND_TRUTH")
    assert out.read_bytes() == out2.read_bytes()


def test_agents_beyond_range_are_unknown(drive, tmp_path):
    out = tmp_path / "occ.lcm"
    replay(drive, out, "--pose-channel", "GROUND_TRUTH")
    far = 0
    for m in occlusions(out):
        for a in m.agents:
            if a.nsamples and math.dist((a.sample_x[0], a.sample_y[0], 0), (m.viewer[0], m.viewer[1], 0)) > 60:
                far += 1
                assert set(a.state) == {2} and a.visible_fraction == 0
    assert far > 100


def test_lost_pose_makes_every_sample_unknown(drive, tmp_path):
    """GROUND_TRUTH becomes POSE; between 4 and 7 s its status is lost, then initializing."""
    import lcm
    from portobello import pose_t
    lost = tmp_path / "lost.lcm"
    src = lcm.EventLog(str(drive), "r")
    dst = lcm.EventLog(str(lost), "w", overwrite=True)
    t0 = None
    for ev in src:
        t0 = ev.timestamp if t0 is None else t0
        ch, data = ev.channel, ev.data
        if ch == "GROUND_TRUTH":
            p = pose_t.decode(data)
            dt = (p.utime - t0) * 1e-6
            if 4 <= dt < 5.5:
                p.status = pose_t.STATUS_LOST
            elif 5.5 <= dt < 7:
                p.status = pose_t.STATUS_INITIALIZING
            ch, data = "POSE", p.encode()
        dst.write_event(ev.timestamp, ch, data)
    dst.close()
    out = tmp_path / "occ.lcm"
    replay(lost, out)
    occ = occlusions(out)
    assert len(occ) == 120
    during = [m for m in occ if 4.15 <= (m.utime - t0) * 1e-6 < 7]
    assert len(during) >= 25
    for m in during:
        for a in m.agents:
            assert all(s == 2 for s in a.state), "a sample without a usable pose must be unknown"
    after = [m for m in occ if (m.utime - t0) * 1e-6 > 7.3]
    assert any(s == 0 for m in after for a in m.agents for s in a.state)      # back once tracking
    st = statuses(out)
    assert counter(st[-1], "sweep_without_pose") >= 25
    assert any("no usable pose" in s.last_error for s in st)


def test_missing_head_pose_falls_back_to_the_seat(drive, tmp_path):
    nohead = tmp_path / "nohead.lcm"
    run([PY, FAULT, "drop-channel", "--channel", "HEAD_POSE", "--in", drive, "--out", nohead])
    out = tmp_path / "occ.lcm"
    replay(nohead, out, "--pose-channel", "GROUND_TRUTH")
    from portobello import occlusion_t
    occ = occlusions(out)
    assert occ and all(m.eye_source == occlusion_t.EYE_SEAT for m in occ)
    st = statuses(out)
    assert counter(st[-1], "eye_seat_fallback") == 1
    assert any("seat" in s.last_error for s in st)
    assert any(s.state == s.STATE_DEGRADED for s in st)
    # the truth's eye moved with the simulated head: the seat is close (a few cm), so the
    # states still mostly agree (measured 0.949: error 0.051, bound 3x)
    assert agreement(drive, out)["agreement"] >= 0.846


def test_headset_clock_offset_is_measured_and_taken_out(drive, tmp_path):
    """A headset whose clock is 3 s ahead of the car's (log-fault head-clock; a headset is a
    device of its own, seldom synchronised with the car): its HEAD_POSE would all look 3 s
    stale, and the eye would fall back to the seat. The module measures the offset from when
    the head poses arrive among the poses and sweeps, says so, takes it out, and answers as
    with a headset on the car's clock, sweep for sweep."""
    shifted = tmp_path / "head3.lcm"
    run([PY, FAULT, "head-clock", "--seconds", "3", "--in", drive, "--out", shifted])
    out, ref = tmp_path / "occ.lcm", tmp_path / "ref.lcm"
    replay(shifted, out, "--pose-channel", "GROUND_TRUTH")
    replay(drive, ref, "--pose-channel", "GROUND_TRUTH")
    from portobello import occlusion_t
    occ = occlusions(out)
    assert len(occ) == 120 and all(m.eye_source == occlusion_t.EYE_HEAD_POSE for m in occ)
    assert [m.encode() for m in occ] == [m.encode() for m in occlusions(ref)]
    st = statuses(out)
    assert counter(st[-1], "head_clock_offset") == 1 and counter(st[-1], "eye_seat_fallback") == 0
    import re
    said = [float(m.group(1)) for s in st for m in [re.search(r"its clock ([+-][0-9.]+) s off the car's, corrected",
                                                             s.last_error)] if m]
    # measured (5 Dec): +2.97 s (a head pose's lag behind the newest pose or sweep end: the
    # simulated head and GROUND_TRUTH both at 100 Hz)
    assert said and all(2.9 <= v <= 3.05 for v in said), said


def test_nan_points_are_dropped_and_counted(drive, tmp_path):
    bad = tmp_path / "nan.lcm"
    run([PY, FAULT, "nan-points", "--at", "3", "--count", "5", "--in", drive, "--out", bad])
    out = tmp_path / "occ.lcm"
    replay(bad, out, "--pose-channel", "GROUND_TRUTH")
    occ = occlusions(out)
    assert len(occ) == 120
    for m in occ:
        for a in m.agents:
            assert all(s in (0, 1, 2) for s in a.state)
            assert all(math.isfinite(v) for v in a.sample_x)
    st = statuses(out)
    assert counter(st[-1], "scan_nonfinite_points") > 0
    assert agreement(drive, out)["agreement"] >= 0.842   # measured 0.947, as without the fault (error 0.053, bound 3x)


def test_changes_followed_causes():
    """The bench's "every change within one scan" count on hand-made series of
    (sweep, truth, module): which changes are judged and why the others are not followed."""
    from occ_agreement import changes_followed
    series = {
        0: [(0, 0, 0), (1, 1, 1), (2, 1, 1)],                        # followed at once
        1: [(0, 0, 0), (1, 1, 0), (2, 0, 0)],                        # truth hidden for one sweep only
        2: [(0, 1, 1), (1, 0, 1), (2, 0, 1), (3, 0, 0)],             # visible two sweeps late
        3: [(0, 1, 1), (1, 0, 2), (2, 0, 2)],                        # module unknown
        4: [(0, 1, 1), (1, 0, 1)],                                   # sample leaves range
        5: [(0, 1, 1), (1, 0, 1), (2, 0, 1), (3, 0, 1), (4, 0, 0)],  # three sweeps late
        6: [(0, 1, 1), (1, 0, 1), (2, 0, 1), (3, 1, 1)],             # never, then followed
    }
    c = changes_followed(series)
    assert (c["changes"], c["followed"], c["followable"], c["followed_followable"]) == (9, 3, 5, 1)
    nf = c["not_followed"]
    assert nf["truth_flicker"] == {"to_visible": 0, "to_hidden": 1}
    for cause in ("late_by_1", "module_unknown", "sample_leaves", "late_by_2_or_more", "never"):
        assert nf[cause] == {"to_visible": 1, "to_hidden": 0}, cause
