"""modules/director and tools/scenario-check: the scenario runtime on simulated drives.

Drives come from simdrive (road car, GROUND_TRUTH, no LiDAR) and lab_vehicle (the
in-lab twin, POSE), shared by module-scoped fixtures. Each test decodes what the
director wrote and checks it against geometry computed here independently.
"""
import importlib.util
import math
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from conftest import BIN, ROOT, read_log, run

sys.path.insert(0, str(ROOT / "build" / "python"))
import lcm  # noqa: E402
import portobello  # noqa: E402

SITE = ROOT / "maps" / "default"
SCEN = SITE / "scenarios"
STUDY = sorted(p.stem for p in SCEN.glob("*.yaml"))
FOUR = [s for s in STUDY if s.startswith("cw")]
VEH = yaml.safe_load(open(ROOT / "vehicles" / "prius2017.yaml"))["dimensions"]


# ---------------------------------------------------------------- helpers
def director(drive, out, scenario="cw01_look_and_cross", *extra, channel="GROUND_TRUTH", check=True):
    args = [BIN / "director", "--site", SITE, "--scenario", scenario, "--replay", drive, "--out", out, *extra]
    if channel:
        args += ["--pose-channel", channel]
    return run(args, check=check)


def events(log, kinds=None):
    out = []
    for ch, _, data in read_log(log, {"SCENARIO_EVENT"}):
        e = portobello.scenario_event_t.decode(data)
        if kinds is None or e.kind in kinds:
            out.append(e)
    return out


def poses(log, channel):
    t, xy, yaw, v = [], [], [], []
    for _, _, data in read_log(log, {channel}):
        m = portobello.pose_t.decode(data)
        q = m.orientation
        t.append(m.utime); xy.append(m.position[:2]); v.append(math.hypot(*m.velocity[:2]))
        yaw.append(math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2)))
    return np.array(t, dtype=np.int64), np.array(xy), np.array(yaw), np.array(v)


def footprint(x, y, yaw):
    """The car's box in the ground plane: 4 corners (base origin at the rear axle)."""
    L, W, ro = VEH["length"], VEH["width"], VEH["rear_overhang"]
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([(x + u * c - w * s, y + u * s + w * c) for u, w in ((-ro, -W / 2), (L - ro, -W / 2), (L - ro, W / 2), (-ro, W / 2))])


def polys_touch(a, b):
    """Separating-axis test of two convex polygons."""
    for P in (a, b):
        for i in range(len(P)):
            e = P[(i + 1) % len(P)] - P[i]
            n = np.array([-e[1], e[0]])
            pa, pb = a @ n, b @ n
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def poly_circle_touch(p, c, r):
    def cross(a, b):
        return a[0] * b[1] - a[1] * b[0]
    inside = all(cross(p[(i + 1) % 4] - p[i], c - p[i]) >= 0 for i in range(4))
    if inside:
        return True
    for i in range(4):
        a, b = p[i], p[(i + 1) % 4]
        f = np.clip(np.dot(c - a, b - a) / np.dot(b - a, b - a), 0, 1)
        if np.linalg.norm(a + f * (b - a) - c) <= r:
            return True
    return False


def volume_touch(vol, foot):
    if vol["type"] == "box":
        L, W = vol["size"][:2]
        yaw = math.radians(vol.get("yaw_deg", 0))
        c, s = math.cos(yaw), math.sin(yaw)
        cx, cy = vol["center"]
        box = np.array([(cx + u * c - w * s, cy + u * s + w * c) for u, w in ((-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, W / 2), (-L / 2, W / 2))])
        return polys_touch(foot, box)
    if vol["type"] == "prism":
        return polys_touch(foot, np.array(vol["points"]))
    return poly_circle_touch(foot, np.array(vol["center"]), vol["radius"])


def first_contact(track, vol, after_us=0):
    """Base position where the footprint first touches vol (bisection between poses)."""
    t, xy, yaw, _ = track
    prev = None
    for i in range(len(t)):
        if t[i] < after_us:
            continue
        if volume_touch(vol, footprint(*xy[i], yaw[i])):
            if prev is None:
                return xy[i]
            lo, hi = 0.0, 1.0
            for _ in range(20):
                m = (lo + hi) / 2
                p = xy[prev] + m * (xy[i] - xy[prev])
                y = yaw[prev] + m * math.remainder(yaw[i] - yaw[prev], 2 * math.pi)
                if volume_touch(vol, footprint(*p, y)):
                    hi = m
                else:
                    lo = m
            return xy[prev] + hi * (xy[i] - xy[prev])
        prev = i
    return None


def write_log(path, evs):
    log = lcm.EventLog(str(path), "w", overwrite=True)
    for ch, ts, data in evs:
        log.write_event(ts, ch, data)
    log.close()


# ---------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def road(tmp):
    d = tmp / "road"
    run([BIN / "simdrive", "--no-lidar", "--quiet", "--seed", 3, "--duration", 75, "--out", d])
    return d / "drive.lcm"


@pytest.fixture(scope="module")
def lab(tmp):
    assert (BIN / "lab_vehicle").exists(), "build/bin/lab_vehicle not built: make test builds it"
    out = tmp / "lab.lcm"
    run([BIN / "lab_vehicle", "--site", SITE, "--out", out, "--auto-proceed", 2.0, "--duration", 80])
    return out


# ---------------------------------------------------------------- format and loader
BAD = [
    ("unknown key", "scenario: x\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions: [{type: emit, event: e, colour: red}]\n", 5, "colour"),
    ("unknown volume", "scenario: x\ntriggers:\n  - id: t\n    when: {type: enter, volume: nowhere}\n    actions: [{type: emit, event: e}]\n", 4, "unknown volume 'nowhere'"),
    ("unknown stop line", "scenario: x\ntriggers:\n  - id: t\n    when: {type: distance, stop_line: sl99, below: 3}\n    actions: [{type: emit, event: e}]\n", 4, "sl99"),
    ("unknown behaviour", "scenario: x\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions:\n      - {type: start, behaviour: walk}\n", 6, "unknown behaviour 'walk'"),
    ("unknown trigger in after", "scenario: x\ntriggers:\n  - id: t\n    when: {type: after, trigger: t0}\n    actions: [{type: emit, event: e}]\n", 4, "unknown trigger 't0'"),
    ("duplicate agent", "scenario: x\nagents:\n  - {id: p, kind: pedestrian, model: m, start: [0, 0]}\n  - {id: p, kind: pedestrian, model: m, start: [1, 0]}\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions: [{type: emit, event: e}]\n", 4, "duplicate agent id 'p'"),
    ("concave prism", "scenario: x\nvolumes:\n  - {id: v, type: prism, points: [[0, 0], [4, 0], [1, 1], [0, 4]], z: [0, 2]}\ntriggers:\n  - id: t\n    when: {type: enter, volume: v}\n    actions: [{type: emit, event: e}]\n", 3, "not strictly convex"),
    ("key of another volume type", "scenario: x\nvolumes:\n  - {id: v, type: cylinder, center: [0, 0], radius: 2, size: [1, 1, 1]}\ntriggers:\n  - id: t\n    when: {type: enter, volume: v}\n    actions: [{type: emit, event: e}]\n", 3, "'size' does not apply"),
    ("bad edge", "scenario: x\ntriggers:\n  - id: t\n    when: {type: speed, above: 1, edge: up}\n    actions: [{type: emit, event: e}]\n", 4, "edge 'up'"),
    ("sync mark out of range", "scenario: x\nagents:\n  - {id: p, kind: pedestrian, model: m, start: [0, 0]}\nbehaviours:\n  - id: b\n    agent: p\n    path: [{to: [1, 0]}]\n    sync: {mark: 3, stop_line: sl01}\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions: [{type: start, behaviour: b}]\n", 8, "mark"),
    ("speed out of range", "scenario: x\nagents:\n  - {id: p, kind: pedestrian, model: m, start: [0, 0]}\nbehaviours:\n  - id: b\n    agent: p\n    path: [{to: [1, 0], speed: 90}]\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions: [{type: start, behaviour: b}]\n", 7, "speed"),
    ("animation of two words", "scenario: x\nagents:\n  - {id: p, kind: pedestrian, model: m, start: [0, 0]}\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions:\n      - {type: animate, agent: p, animation: look left}\n", 8, "one word"),
    ("quoted number", "scenario: x\nrender_distance_m: \"45\"\ntriggers:\n  - id: t\n    when: {type: time, above: 1}\n    actions: [{type: emit, event: e}]\n", 2, "render_distance_m"),
]


@pytest.mark.parametrize("name,text,line,what", BAD, ids=[b[0] for b in BAD])
def test_scenario_errors_name_file_and_line_and_nothing_starts(tmp, road, name, text, line, what):
    f = tmp / f"bad_{name.replace(' ', '_')}.yaml"
    f.write_text(text)
    out = tmp / f"bad_{name.replace(' ', '_')}.lcm"
    p = director(road, out, f, check=False)
    assert p.returncode == 1, p.stderr
    assert f"{f}:{line}:" in p.stderr and what in p.stderr, p.stderr
    assert not out.exists(), "the director opened its output although the scenario was refused"
    c = run([BIN / "scenario-check", "--site", SITE, f], check=False)
    assert c.returncode == 1 and f"{f}:{line}:" in c.stdout and what in c.stdout, c.stdout


def test_shipped_study_checks_clean_and_has_twelve_pedestrians():
    assert FOUR == ["cw01_look_and_cross", "cw02_stop_at_kerb", "cw03_walk_past", "cw04_cross_far_side"]
    assert STUDY == ["crosswalk_study"] + FOUR
    c = run([BIN / "scenario-check", "--site", SITE])
    assert c.stdout.count(": ok") == 5 and "warning" not in c.stdout, c.stdout
    peds = sum(sum(a["kind"] == "pedestrian" for a in yaml.safe_load(open(SCEN / f"{s}.yaml"))["agents"]) for s in FOUR)
    assert peds == 12
    whole = yaml.safe_load(open(SCEN / "crosswalk_study.yaml"))
    assert sorted(a["id"] for a in whole["agents"]) == sorted(
        a["id"] for s in FOUR for a in yaml.safe_load(open(SCEN / f"{s}.yaml"))["agents"])
    for s in STUDY:
        doc = yaml.safe_load(open(SCEN / f"{s}.yaml"))
        assert any("sync" in b for b in doc["behaviours"]), s


def test_scenario_check_finds_volumes_off_route_and_unreachable_marks(tmp):
    doc = yaml.safe_load(open(SCEN / "cw03_walk_past.yaml"))
    doc["volumes"].append({"id": "far_away", "type": "cylinder", "center": [300.0, 90.0], "radius": 2.0, "height": 3.0})
    doc["triggers"].append({"id": "never", "when": {"type": "enter", "volume": "far_away"}, "actions": [{"type": "emit", "event": "x"}]})
    main = doc["agents"][0]
    main["start"] = [main["start"][0] + 30.0, main["start"][1]]     # 30 m further: too far for 1.8 m/s
    f = tmp / "offroute.yaml"
    yaml.safe_dump(doc, open(f, "w"), sort_keys=False)
    c = run([BIN / "scenario-check", "--site", SITE, f], check=False)
    assert c.returncode == 1
    assert "volume 'far_away' is off the route" in c.stdout
    assert "cannot reach its mark" in c.stdout and "ped_c_main" in c.stdout
    lines = [l for l in c.stdout.splitlines() if "error:" in l]
    assert all(l.startswith(f"{f}:") and l.split(":")[1].isdigit() for l in lines), lines


# ---------------------------------------------------------------- the runtime on a road drive
def test_road_drive_fires_every_trigger_once_where_the_footprint_first_touches(tmp, road):
    track = poses(road, "GROUND_TRUTH")
    for name in STUDY:
        out = tmp / f"road_{name}.lcm"
        director(road, out, name)
        doc = yaml.safe_load(open(SCEN / f"{name}.yaml"))
        vols = {v["id"]: v for v in doc["volumes"]}
        trig = [e for e in events(out, {"trigger"})]
        ids = [e.event_id for e in trig]
        assert sorted(ids) == sorted(t["id"] for t in doc["triggers"]), (name, ids)
        assert len(ids) == len(set(ids))
        for t in doc["triggers"]:
            w = t["when"]
            if w.get("type") != "enter":
                continue
            ev = next(e for e in trig if e.event_id == t["id"])
            after = 0
            if w.get("edge") == "rising":   # a rising edge needs the car outside first
                after = track[0][0] + 1
            contact = first_contact(track, vols[w["volume"]], after)
            assert contact is not None
            err = math.hypot(ev.vehicle.position[0] - contact[0], ev.vehicle.position[1] - contact[1])
            # the event carries the contact interpolated between poses: measured 0.1 mm at 100 Hz
            # on the flat site, 3.9 mm on the default site's relief (the director tests the car's
            # pitched and rolled box in 3-D, this check its flat footprint): bound ~3x
            assert err <= 0.012, f"{name}/{t['id']}: fired {err:.4f} m from the first contact"


def test_a_10_hz_pose_places_triggers_where_100_hz_does(tmp, road):
    """The localizer's POSE comes at 10 Hz: at 10 m/s a trigger tested only at each pose
    would fire up to 1 m late. Every 10th GROUND_TRUTH pose alone gives the same events,
    every enter trigger at the first contact on the full 100 Hz track."""
    evs = list(read_log(road))
    gt = [e for e in evs if e[0] == "GROUND_TRUTH"]
    keep = {e[1] for e in gt[::10]}
    sparse = tmp / "sparse_10hz.lcm"
    write_log(sparse, [e for e in evs if e[0] != "GROUND_TRUTH" or e[1] in keep])
    track = poses(road, "GROUND_TRUTH")
    for name in FOUR:
        full, thin = tmp / f"full_{name}.lcm", tmp / f"thin_{name}.lcm"
        director(road, full, name)
        director(sparse, thin, name)
        kinds = {"trigger", "action", "mark"}
        assert [(e.kind, e.event_id) for e in events(full, kinds)] == [(e.kind, e.event_id) for e in events(thin, kinds)]
        doc = yaml.safe_load(open(SCEN / f"{name}.yaml"))
        vols = {v["id"]: v for v in doc["volumes"]}
        for t in doc["triggers"]:
            w = t["when"]
            if w.get("type") != "enter":
                continue
            ev = next(e for e in events(thin, {"trigger"}) if e.event_id == t["id"])
            c = first_contact(track, vols[w["volume"]], track[0][0] + 1 if w.get("edge") == "rising" else 0)
            # measured 0.9 mm flat (interpolation between poses 1 m apart; at the pose alone up to
            # 1 m), 3.9 mm on the default site's relief (3-D box vs this flat footprint): bound ~3x
            assert math.hypot(ev.vehicle.position[0] - c[0], ev.vehicle.position[1] - c[1]) <= 0.012, (name, t["id"])
            assert ev.utime == ev.vehicle.utime


def test_replay_is_deterministic_and_agents_are_flagged_not_dropped(tmp, road):
    a, b = tmp / "det_a.lcm", tmp / "det_b.lcm"
    director(road, a, "cw02_stop_at_kerb", "--rate", "30")
    director(road, b, "cw02_stop_at_kerb", "--rate", "30")
    assert a.read_bytes() == b.read_bytes()
    msgs = [portobello.agents_t.decode(d) for _, _, d in read_log(a, {"AGENTS"})]
    t = np.array([m.utime for m in msgs])
    rate = (len(t) - 1) / ((t[-1] - t[0]) * 1e-6)
    assert 29.0 < rate < 31.0
    assert all(m.nagents == 3 for m in msgs)
    far = [ag for m in msgs for ag in m.agents if ag.distance_m > 45.0]
    near = [ag for m in msgs for ag in m.agents if 0 <= ag.distance_m <= 45.0]
    assert far and near
    assert not any(ag.in_render_range for ag in far) and all(ag.in_render_range for ag in near)


def test_arrival_synchronised_pedestrian_reaches_the_kerb_when_the_car_stops(tmp, road):
    out = tmp / "sync.lcm"
    director(road, out, "cw01_look_and_cross")
    mark = next(e for e in events(out, {"mark"}))
    t, xy, _, v = poses(road, "GROUND_TRUTH")
    stop = np.array(yaml.safe_load(open(SITE / "route.yaml"))["stop_lines"][0]["xy"])
    rest = next(t[i] for i in range(len(t)) if t[i] > t[0] + 2e6 and v[i] < 0.05 and np.linalg.norm(xy[i] - stop) < 7.5)
    # the mark event carries the exact instant in its detail ("at t=..." since the first pose)
    t_mark = t[0] + float(mark.detail.split("at t=")[1].split(" ")[0]) * 1e6
    assert abs(t_mark - rest) * 1e-6 <= 0.3, f"pedestrian at the kerb {(t_mark - rest) * 1e-6:+.3f} s from the car's stop"
    # and the kerb position is where the file puts it
    doc = yaml.safe_load(open(SCEN / "cw01_look_and_cross.yaml"))
    kerb = doc["behaviours"][0]["path"][1]["to"]
    assert math.hypot(mark.agent_position[0] - kerb[0], mark.agent_position[1] - kerb[1]) < 1e-6
    speeds = [math.hypot(*ag.velocity[:2]) for _, ts, d in read_log(out, {"AGENTS"}) if ts <= mark.utime
              for ag in portobello.agents_t.decode(d).agents if ag.id == "ped_a_main" and ag.animation == "walk"]
    assert speeds and min(speeds) >= 0.8 - 1e-6 and max(speeds) <= 1.8 + 1e-6


def test_virtual_collision_carries_both_poses(tmp, road):
    out = tmp / "collide.lcm"
    director(road, out, "cw01_look_and_cross")   # simdrive's car does not yield to the crossing pedestrian
    col = events(out, {"collision"})
    assert len(col) == 1 and col[0].agent_id == "ped_a_main"
    e = col[0]
    # the car's box in 3-D (pitched and rolled on the terrain) touches the pedestrian's
    # cylinder (radius 0.3 m, 1.8 m tall from its feet): the nearest point of the
    # cylinder's axis to the box is within the radius
    w, x, y, z = e.vehicle.orientation
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    axis = np.array(e.agent_position) + np.outer(np.linspace(0, 1.8, 721), [0, 0, 1])
    local = (axis - np.array(e.vehicle.position)) @ R      # base frame (rows: R^T p)
    lo = np.array([-VEH["rear_overhang"], -VEH["width"] / 2, 0.0])
    hi = np.array([VEH["length"] - VEH["rear_overhang"], VEH["width"] / 2, VEH["height"]])
    dist = np.linalg.norm(np.maximum(np.maximum(lo - local, local - hi), 0), axis=1).min()
    assert dist <= 0.3 + 1e-3, dist


# ---------------------------------------------------------------- restart, jumps, stale poses
def test_restart_mid_drive_fires_no_trigger_twice(tmp, road):
    full = tmp / "full.lcm"
    director(road, full, "cw01_look_and_cross")
    ref = [(e.kind, e.event_id) for e in events(full, {"trigger", "action", "mark"})]
    evs = list(read_log(road))
    cut = evs[0][1] + 12_000_000     # 12 s in: after car_approaches, before the car stops
    part1, part2 = tmp / "part1.lcm", tmp / "part2.lcm"
    write_log(part1, [e for e in evs if e[1] < cut])
    write_log(part2, [e for e in evs if e[1] >= cut + 500_000])   # 0.5 s of downtime
    state = tmp / "director.state"
    if state.exists():
        state.unlink()
    o1, o2 = tmp / "out1.lcm", tmp / "out2.lcm"
    director(part1, o1, "cw01_look_and_cross", "--state", state)
    assert "fired car_approaches" in state.read_text()
    p = director(part2, o2, "cw01_look_and_cross", "--state", state)
    assert "recovered 1 fired trigger" in p.stderr
    got = [(e.kind, e.event_id) for e in events(o1, {"trigger", "action", "mark"}) + events(o2, {"trigger", "action", "mark"})]
    assert got == ref
    # the recovered pedestrian finishes its synchronised walk; without the state it never starts
    assert [e.kind for e in events(o2, {"mark"})] == ["mark"]
    o3 = tmp / "out3.lcm"
    director(part2, o3, "cw01_look_and_cross")
    assert events(o3, {"mark"}) == []


def test_pose_jump_across_a_volume_is_reported_not_fired(tmp, road):
    evs = list(read_log(road))
    t, xy, yaw, _ = poses(road, "GROUND_TRUTH")
    doc = yaml.safe_load(open(SCEN / "cw01_look_and_cross.yaml"))
    vol = next(v for v in doc["volumes"] if v["id"] == "approach")
    contact = first_contact((t, xy, yaw, None), vol)
    i_touch = int(np.argmin(np.linalg.norm(xy - contact, axis=1)))
    # drop 1.5 s of poses around the contact: the next pose lands 10+ m beyond the volume
    t_lo, t_hi = t[i_touch - 80], t[i_touch + 120]
    jumped = tmp / "jump.lcm"
    write_log(jumped, [e for e in evs if not (e[0] == "GROUND_TRUTH" and t_lo < e[1] < t_hi)])
    for policy, fired in (("skip", False), ("fire", True)):
        d2 = dict(doc, on_pose_jump=policy, pose_jump_m=3.0)
        f = tmp / f"jump_{policy}.yaml"
        yaml.safe_dump(d2, open(f, "w"), sort_keys=False)
        out = tmp / f"jump_{policy}.lcm"
        director(jumped, out, f)
        warn = [e for e in events(out, {"warning"}) if e.event_id == "pose_jump:car_approaches"]
        assert len(warn) == 1 and "approach" in warn[0].detail and policy in warn[0].detail
        ids = [e.event_id for e in events(out, {"trigger"})]
        assert ("car_approaches" in ids) == fired


def test_stale_pose_holds_synchronised_agents_and_says_so_in_status(tmp, road):
    evs = list(read_log(road))
    t0 = evs[0][1]
    gap = (t0 + 8_000_000, t0 + 11_000_000)    # 3 s without GROUND_TRUTH while the pedestrian walks
    gapped = tmp / "gap.lcm"
    write_log(gapped, [e for e in evs if not (e[0] == "GROUND_TRUTH" and gap[0] < e[1] < gap[1])])
    out = tmp / "gap_out.lcm"
    director(gapped, out, "cw01_look_and_cross")
    w = [e.event_id for e in events(out, {"warning"})]
    assert "pose_stale" in w and "pose_resumed" in w
    st = [portobello.status_t.decode(d) for _, ts, d in read_log(out, {"STATUS"}) if gap[0] + 700_000 < ts < gap[1]]
    assert st and all(s.state == portobello.status_t.STATE_DEGRADED and "stale" in s.last_error for s in st)
    main, stroll = [], []
    for _, ts, d in read_log(out, {"AGENTS"}):
        if gap[0] + 600_000 < ts < gap[1]:
            for a in portobello.agents_t.decode(d).agents:
                (main if a.id == "ped_a_main" else stroll if a.id == "ped_a_stroll" else []).append(tuple(a.position[:2]))
    assert len(set(main)) == 1, "the synchronised pedestrian moved without a vehicle pose"
    assert len(set(stroll)) > 10, "an unsynchronised walk should go on"


# ---------------------------------------------------------------- lab and road
def test_same_scenario_same_event_sequence_in_the_lab_and_on_the_road(tmp, road, lab):
    for name in STUDY:
        lo, ro = tmp / f"lab_{name}.lcm", tmp / f"roadx_{name}.lcm"
        director(lab, lo, name, channel="POSE")
        director(road, ro, name)
        seq_lab = [(e.kind, e.event_id, e.agent_id) for e in events(lo)]
        seq_road = [(e.kind, e.event_id, e.agent_id) for e in events(ro)]
        assert seq_lab == seq_road, name
        doc = yaml.safe_load(open(SCEN / f"{name}.yaml"))
        assert sum(k == "trigger" for k, _, _ in seq_lab) == len(doc["triggers"])
        # and on the lab drive every enter trigger fires within 0.2 m of the first contact too
        track = poses(lab, "POSE")
        doc = yaml.safe_load(open(SCEN / f"{name}.yaml"))
        vols = {v["id"]: v for v in doc["volumes"]}
        for t in doc["triggers"]:
            if t["when"].get("type") == "enter":
                ev = next(e for e in events(lo, {"trigger"}) if e.event_id == t["id"])
                c = first_contact(track, vols[t["when"]["volume"]])
                # measured 0.6 mm flat (the interpolated contact; at the pose it was up to 0.14 m),
                # 3.6 mm on the default site's relief (3-D box vs this flat footprint): bound ~3x
                assert math.hypot(ev.vehicle.position[0] - c[0], ev.vehicle.position[1] - c[1]) <= 0.011


# ---------------------------------------------------------------- live bus
URL = "udpm://239.255.76.67:7771?ttl=0&recv_buf_size=8388608"


@pytest.mark.live
def test_live_bus_poses_in_agents_and_events_out():
    lc = lcm.LCM(URL)
    got = {"AGENTS": [], "SCENARIO_EVENT": [], "STATUS": []}
    for ch in got:
        lc.subscribe(ch, lambda c, d: got[c].append(d))
    p = subprocess.Popen([str(BIN / "director"), "--site", str(SITE), "--scenario", "cw02_stop_at_kerb", "--lcm-url", URL],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        end = time.time() + 1.5
        while time.time() < end:        # no POSE yet: STATUS says so
            lc.handle_timeout(100)
        assert any("no POSE yet" in portobello.status_t.decode(d).last_error for d in got["STATUS"])
        doc = yaml.safe_load(open(SCEN / "cw02_stop_at_kerb.yaml"))
        vol = next(v for v in doc["volumes"] if v["id"] == "approach")
        yaw = math.radians(vol["yaw_deg"])
        spec = importlib.util.spec_from_file_location("bench_terrain", ROOT / "tools" / "bench-terrain" / "bench.py")
        gm = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(gm)
        ground = gm.read_ground(SITE / "ground.yaml")     # the poses ride the site's ground
        t0 = int(time.time() * 1e6)
        for i in range(150):            # 1.5 s at 100 Hz, driving through the approach volume at 10 m/s
            m = portobello.pose_t()
            m.utime = t0 + i * 10000
            s = -8.0 + 0.1 * i
            px, py = vol["center"][0] + s * math.cos(yaw), vol["center"][1] + s * math.sin(yaw)
            m.position = [px, py, float(gm.sample(ground, np.array([px]), np.array([py]))[0])]
            m.orientation = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
            m.velocity = [10 * math.cos(yaw), 10 * math.sin(yaw), 0.0]
            m.status = portobello.pose_t.STATUS_TRACKING
            lc.publish("POSE", m.encode())
            lc.handle_timeout(10)
        end = time.time() + 1.0
        while time.time() < end:
            lc.handle_timeout(50)
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(timeout=10)
    ev = [portobello.scenario_event_t.decode(d) for d in got["SCENARIO_EVENT"]]
    assert [e.event_id for e in ev if e.kind == "trigger"] == ["car_approaches"]
    assert len(got["AGENTS"]) > 30
    assert "pose_stale" in [e.event_id for e in ev]     # the poses stopped: reported
    assert p.returncode == 0


def test_help_and_bad_options():
    assert "--scenario" in run([BIN / "director", "--help"]).stdout
    assert "--site" in run([BIN / "scenario-check", "--help"]).stdout
    p = run([BIN / "director", "--site", SITE, "--scenario", "cw01_look_and_cross", "--rate", "200"], check=False)
    assert p.returncode == 2 and "--rate" in p.stderr
    p = run([BIN / "director", "--site", SITE], check=False)
    assert p.returncode == 2


@pytest.mark.live
def test_live_closed_loop_with_the_lab_twin_yields_to_the_crossing_pedestrian():
    """director and lab_vehicle live on one bus: the twin waits at sl01 until the
    synchronised pedestrian has crossed (AGENTS), so no virtual collision happens."""
    assert (BIN / "lab_vehicle").exists(), "build/bin/lab_vehicle not built: make test builds it"
    url = "udpm://239.255.76.67:7772?ttl=0&recv_buf_size=8388608"
    lc = lcm.LCM(url)
    evs = []
    for ch in ("SCENARIO_EVENT", "LAB_EVENT"):
        lc.subscribe(ch, lambda c, d: evs.append(portobello.scenario_event_t.decode(d)))
    d = subprocess.Popen([str(BIN / "director"), "--site", str(SITE), "--scenario", "cw01_look_and_cross", "--lcm-url", url],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    v = subprocess.Popen([str(BIN / "lab_vehicle"), "--site", str(SITE), "--lcm-url", url, "--duration", "34"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0, last = time.time(), 0.0
        while time.time() - t0 < 35 and v.poll() is None:
            lc.handle_timeout(50)
            if time.time() - last > 1.0:       # the participant keeps pressing proceed
                m = portobello.participant_input_t()
                m.utime, m.input, m.device, m.value = int(time.time() * 1e6), "proceed", "test", 1
                lc.publish("PARTICIPANT_INPUT", m.encode())
                last = time.time()
    finally:
        v.send_signal(signal.SIGINT)
        d.send_signal(signal.SIGINT)
        v.wait(timeout=10)
        d.wait(timeout=10)
    seq = [(e.kind, e.event_id, e.agent_id) for e in sorted(evs, key=lambda e: e.utime)]
    ids = [s[1] for s in seq]
    assert ("lab", "crossing_occupied", "ped_a_main") in seq, seq
    assert "crossing_clear" in ids and "car_on_crosswalk" in ids, seq
    assert ids.index("crossing_clear") < ids.index("car_on_crosswalk")
    assert not any(k == "collision" for k, _, _ in seq), seq
