"""simdrive's messier drive day (tools/simdrive/actors.c), each group switched on with --with:

- lead: a lead car in the car's own lane; the car follows it, stops behind it (the LiDAR
  sees its rear bumper the model's standstill gap ahead) and still rests at every stop
  line; its speed curve is no longer the planner's;
- crossing, pedestrians: cars crossing at junctions and people on sidewalks and
  crosswalks, LiDAR-visible where world.yaml's crossers put them, never inside the car;
- roof: returns from the car's own body where the mount lets beams reach it (none from
  the Prius's 1.95 m mount; over a quarter of the pixels from a mount 13 cm above it);
- every combination is deterministic for a seed; bad names are refused.
"""
import math

import numpy as np
import pytest
import yaml

from conftest import BIN, ROOT
import test_simdrive as ts

SITE = ROOT / "maps" / "default"
WORLD = yaml.safe_load((SITE / "world.yaml").read_text())
ROUTE = yaml.safe_load((SITE / "route.yaml").read_text())


def stop_points(vehicle):
    """Where the base origin rests at each stop line (front bumper 0.5 m behind it)."""
    d = vehicle["dimensions"]
    back = d["length"] - d["rear_overhang"] + 0.5
    out = []
    for s in ROUTE["stop_lines"]:
        y = math.radians(s["yaw_deg"])
        out.append((s["xy"][0] - back * math.cos(y), s["xy"][1] - back * math.sin(y)))
    return np.array(out)


def rests(d, vmin=0.02, tmin=0.5):
    """(start utime, end utime, position) of every rest of tmin s or more after the start."""
    still = d.gt_speed < vmin
    out, i = [], 0
    while i < len(still):
        if still[i]:
            j = i
            while j < len(still) and still[j]:
                j += 1
            if (d.gt_t[j - 1] - d.gt_t[i]) * 1e-6 >= tmin and d.gt_t[i] > d.gt_t[0] + 1.5e6:
                out.append((d.gt_t[i], d.gt_t[j - 1], d.gt_pos[i, :2]))
            i = j
        else:
            i += 1
    return out


@pytest.fixture(scope="module")
def lead_drive(tmp):
    ts.simdrive(tmp / "lead", "--seed", 1, "--duration", 120, "--no-lidar", "--with", "lead", "--driver-spread", 0.2)
    ts.simdrive(tmp / "alone", "--seed", 1, "--duration", 120, "--no-lidar", "--driver-spread", 0.2)
    return ts.Drive(tmp / "lead", 120.0), ts.Drive(tmp / "alone", 120.0)


def test_lead_car_is_followed_and_stopped_behind(lead_drive, vehicle):
    lead, alone = lead_drive
    sp = stop_points(vehicle)
    at_line, queued = 0, 0
    for t0, t1, p in rests(lead):
        dmin = np.min(np.hypot(sp[:, 0] - p[0], sp[:, 1] - p[1]))
        if dmin < 0.2:
            at_line += 1
        else:
            queued += 1
            # queued behind the lead car: short of a stop line by about the lead car's
            # length plus the standstill gap (4.5 + 2.5 m), not somewhere else
            assert 5.0 < dmin < 12.0, (dmin, (t0 - ts.UTIME0) * 1e-6)
    # measured (seed 1, 120 s): 5 rests at a stop line, 1 queued 6.9 m short of one
    assert at_line >= 4 and queued >= 1, (at_line, queued)
    # the car rests at every stop line it passes, as alone (the planner's stops)
    assert at_line >= len([r for r in rests(alone)]) - 2
    # its speed curve is the lead car's, not the planner's: slower on average
    # (measured: 510 m against 661 m alone)
    assert lead.gt_pos.shape == alone.gt_pos.shape
    dist = lambda d: np.sum(np.hypot(*np.diff(d.gt_pos[:, :2], axis=0).T))
    assert dist(lead) < 0.95 * dist(alone), (dist(lead), dist(alone))


def test_lidar_sees_the_lead_car_when_queued(tmp, vehicle):
    """In a queue the rear of the lead car is the standstill gap ahead of the front bumper."""
    # seed 3, cautious: queued behind the lead car at the first stop line from 17.5 to 19.1 s
    ts.simdrive(tmp / "lead_lidar", "--seed", 3, "--duration", 20, "--with", "lead", "--driver-spread", 0.2,
                "--speed-profile", "cautious")
    d = ts.Drive(tmp / "lead_lidar", 20.0)
    sp = stop_points(vehicle)
    dims = vehicle["dimensions"]
    lidar_x = vehicle["sensors"]["lidar"]["xyz"][0]
    expect = dims["length"] - dims["rear_overhang"] - lidar_x + 2.5   # front bumper + IDM's s0
    seen = 0
    for t0, t1, p in rests(d, tmin=0.5):
        if np.min(np.hypot(sp[:, 0] - p[0], sp[:, 1] - p[1])) < 0.2:
            continue
        i = int(np.searchsorted(d.event_times["LIDAR_SCAN"], t0 + 100000))
        if i >= len(d.raw_scans) or d.event_times["LIDAR_SCAN"][i] > t1:
            continue
        xyz, valid, _ = ts.scan_xyz(d.scan(i))
        # the beams straight ahead (columns within 3 degrees of 0) that point down 4 to 16.6
        # degrees, where the lead car's rear (0.2 to 1.65 m high) is 5 m ahead
        ahead = np.r_[0:9, 1016:1024]
        pts = xyz[40:64][:, ahead][valid[40:64][:, ahead]]
        x = pts[np.abs(pts[:, 1]) < 0.5, 0]
        assert len(x) > 10
        # the smoothing of the speed curve leaves the queue within ~0.3 m of the model's gap
        assert abs(np.median(x) - expect) < 0.5, (np.median(x), expect)
        seen += 1
    assert seen >= 1


def crosser_segments():
    segs = []
    for c in WORLD["crossers"]:
        p = np.array(c["path"], dtype=float)
        segs += [(p[i], p[i + 1]) for i in range(len(p) - 1)]
    return segs


def dist_to_segments(xy, segs):
    best = np.full(len(xy), np.inf)
    for a, b in segs:
        ab = b - a
        u = np.clip(((xy - a) @ ab) / (ab @ ab), 0, 1)
        best = np.minimum(best, np.linalg.norm(xy - (a + u[:, None] * ab), axis=1))
    return best


def test_crossers_are_seen_where_their_paths_are(tmp, vehicle):
    """Pixels that differ from the same drive without crossers lie on crossers' paths."""
    args = ["--seed", 3, "--duration", 20, "--speed-profile", "aggressive"]
    ts.simdrive(tmp / "cross", *args, "--with", "crossing,pedestrians")
    ts.simdrive(tmp / "plain", *args)
    a, b = ts.Drive(tmp / "cross", 20.0), ts.Drive(tmp / "plain", 20.0)
    np.testing.assert_array_equal(a.gt_pos, b.gt_pos)      # crossers do not change the car's drive
    segs = crosser_segments()
    changed = 0
    for i in range(len(a.raw_scans)):
        sa, sb = a.scan(i), b.scan(i)
        ra, rb = np.array(sa.range_mm), np.array(sb.range_mm)
        diff = (ra != rb) & (ra > 0)
        if not diff.any():
            continue
        pts, rows = ts.scan_to_map(a, sa, vehicle)
        valid = ra.reshape(sa.rows, sa.cols) > 0
        sel = diff.reshape(sa.rows, sa.cols)[valid]
        p = pts[sel]
        changed += len(p)
        # a return from a crosser's body: within half its width (0.9 m for cars) of its path
        dd = dist_to_segments(p[:, :2], segs)
        assert np.percentile(dd, 99) < 1.0, np.percentile(dd, 99)
        # crossers yield: none of their returns inside the car's footprint (+0.3 m)
        dims = vehicle["dimensions"]
        cx, cy = a.interp(sa.utime, a.gt_pos[:, 0]), a.interp(sa.utime, a.gt_pos[:, 1])
        yaw = a.interp(sa.utime, a.gt_yaw)
        lx = (p[:, 0] - cx) * np.cos(yaw) + (p[:, 1] - cy) * np.sin(yaw)
        ly = -(p[:, 0] - cx) * np.sin(yaw) + (p[:, 1] - cy) * np.cos(yaw)
        inside = ((lx > -dims["rear_overhang"] - 0.3) & (lx < dims["length"] - dims["rear_overhang"] + 0.3)
                  & (np.abs(ly) < dims["width"] / 2 + 0.3))
        assert not inside.any()
    assert changed > 50, changed


def test_surface_distance_finds_the_points_on_road_users(tmp, vehicle):
    """simdrive --surface-distance, given the drive's options, counts the crossers' returns
    (the pixels that differ from the same drive without them) as on moving objects; given the
    options of the drive without crossers, it does not know them and counts (almost) none."""
    import json
    args = ["--seed", 3, "--duration", 20, "--speed-profile", "aggressive"]
    for name, extra in (("cross", ["--with", "crossing,pedestrians"]), ("plain", [])):
        if not (tmp / name / "drive.lcm").exists():
            ts.simdrive(tmp / name, *args, *extra)
    a, b = ts.Drive(tmp / "cross", 20.0), ts.Drive(tmp / "plain", 20.0)
    pts = []
    for i in range(len(a.raw_scans)):
        sa, sb = a.scan(i), b.scan(i)
        ra, rb = np.array(sa.range_mm), np.array(sb.range_mm)
        p, _ = ts.scan_to_map(a, sa, vehicle)
        pts.append(p[((ra != rb) & (ra > 0))[ra > 0]])
    pts = np.concatenate(pts)
    (tmp / "crossers.f32").write_bytes(pts.astype("<f4").tobytes())

    def score(extra, labels=None):
        p = ts.subprocess.run([str(ts.BIN), "--site", str(SITE), *map(str, args), *extra, "--surface-distance",
                               str(tmp / "crossers.f32"), *(["--surface-labels", str(labels)] if labels else [])],
                              capture_output=True, text=True, check=True)
        return json.loads(p.stdout)
    known, unknown = score(["--with", "crossing,pedestrians"], tmp / "labels.u8"), score([])
    # the labels say the same per point: 0 static, 1 off it, 2 on a moving object, 3 own body
    labels = np.frombuffer((tmp / "labels.u8").read_bytes(), np.uint8)
    assert len(labels) == len(pts)
    assert np.count_nonzero(labels == 2) == known["on_moving"]
    assert abs(np.count_nonzero(labels == 0) / len(pts) - known["within_0.05"]) <= 5e-5   # printed to 4 places
    assert np.count_nonzero(labels == 3) == known["on_own_body"] and labels.max() <= 3
    off_static = round(len(pts) * (1 - known["within_0.05"]))
    # measured (27 Nov): 53,047 returns (all on pedestrians in these 20 s), 51,917 of them farther
    # than 5 cm from the static world, 51,915 of those on moving objects; without the crossers, 0
    assert len(pts) > 1000 and known["points"] == len(pts)
    assert known["on_moving"] >= 0.98 * off_static, known
    assert set(known["on_moving_by_class"]) <= {"pedestrian", "vehicle"}, known
    assert unknown["on_moving"] <= 0.02 * len(pts), unknown


def test_surface_distance_counts_nothing_under_the_ground(tmp, vehicle):
    """Road users stand on the ground: the road's own returns placed a few centimetres low (a
    map's pose error) are not on them, although a wheel's or a body's bottom lies as near to
    them as the road; the same returns placed as high are (inside the boxes that passed)."""
    import json
    args = ["--seed", 3, "--duration", 20, "--speed-profile", "aggressive", "--with", "crossing,pedestrians"]
    if not (tmp / "cross" / "drive.lcm").exists():
        ts.simdrive(tmp / "cross", *args)
    a = ts.Drive(tmp / "cross", 20.0)
    pts = np.concatenate([ts.scan_to_map(a, a.scan(i), vehicle)[0] for i in range(0, len(a.raw_scans), 4)])

    def score(p, name):
        f = tmp / f"{name}.f32"
        f.write_bytes(p.astype("<f4").tobytes())
        r = ts.subprocess.run([str(ts.BIN), "--site", str(SITE), *map(str, args), "--surface-distance", str(f),
                               "--surface-labels", str(f) + ".u8"], capture_output=True, text=True, check=True)
        return json.loads(r.stdout), np.frombuffer((tmp / f"{name}.f32.u8").read_bytes(), np.uint8)
    _, labels = score(pts, "returns")
    static = pts[labels == 0]
    low, high = static.copy(), static.copy()
    low[:, 2] -= 0.07
    high[:, 2] += 0.07
    # measured (5 Dec, every 4th sweep): 2,323,387 static returns of 2,440,453; moved 7 cm up,
    # 36,454 of them on road users (31,299 on the bus, 5,128 on pedestrians, 27 on cars); moved
    # 7 cm down, none (21,352 before the rule: the bottoms of the boxes that passed won the tie
    # with the road). Bound: a third of the measured
    assert len(static) > 2000000
    assert score(low, "low")[0]["on_moving"] == 0
    assert score(high, "high")[0]["on_moving"] > 12000


def test_surface_labels_bad_use(tmp):
    """--surface-labels alone is refused; a labels file that cannot be written is an error naming
    it, after the figures are printed."""
    p = ts.subprocess.run([str(ts.BIN), "--site", str(SITE), "--surface-labels", str(tmp / "l.u8")],
                          capture_output=True, text=True)
    assert p.returncode == 2 and "--surface-labels needs --surface-distance" in p.stderr
    pts = tmp / "three.f32"
    pts.write_bytes(np.array([[0, 0, 0], [1, 2, 3], [5, 5, 0.5]], "<f4").tobytes())
    bad = tmp / "no_such_dir" / "l.u8"
    p = ts.subprocess.run([str(ts.BIN), "--site", str(SITE), "--duration", "5", "--surface-distance", str(pts),
                           "--surface-labels", str(bad)], capture_output=True, text=True)
    assert p.returncode == 1 and str(bad) in p.stderr and "cannot write the labels" in p.stderr, p.stderr


def low_mount_vehicle(tmp):
    v = yaml.safe_load(ts.VEHICLE.read_text())
    v["dbc"] = str(ts.DBC)
    v["sensors"]["lidar"]["xyz"][2] = v["dimensions"]["height"] + 0.13
    path = tmp / "prius_low_mount.yaml"
    path.write_text(yaml.safe_dump(v))
    return path, v


def body_pixels(scan, v):
    """Pixels whose point (base frame) lies inside the car's bounding box."""
    xyz, valid, _ = ts.scan_xyz(scan)
    lid = v["sensors"]["lidar"]
    p = xyz @ ts.rpy_matrix(lid.get("rpy_deg", [0, 0, 0])).T + np.array(lid["xyz"])
    d = v["dimensions"]
    inside = (valid & (p[..., 0] > -d["rear_overhang"] - 0.05) & (p[..., 0] < d["length"] - d["rear_overhang"] + 0.05)
              & (np.abs(p[..., 1]) < d["width"] / 2 + 0.05) & (p[..., 2] < d["height"] + 0.05))
    return inside


def test_roof_returns_follow_the_mount(tmp, vehicle):
    ts.simdrive(tmp / "roof_prius", "--seed", 1, "--duration", 1, "--with", "roof")
    d = ts.Drive(tmp / "roof_prius", 1.0)
    # the OS1-64's lowest beam (-16.6 deg) from 0.48 m above the roof clears the Prius
    assert all(body_pixels(d.scan(i), vehicle).sum() == 0 for i in range(len(d.raw_scans)))
    path, low = low_mount_vehicle(tmp)
    ts.simdrive(tmp / "roof_low", "--seed", 1, "--duration", 1, "--with", "roof", "--vehicle", path)
    ts.simdrive(tmp / "noroof_low", "--seed", 1, "--duration", 1, "--vehicle", path)
    a, b = ts.Drive(tmp / "roof_low", 1.0), ts.Drive(tmp / "noroof_low", 1.0)
    counts = []
    for i in range(len(a.raw_scans)):
        counts.append(body_pixels(a.scan(i), low).sum())
        assert body_pixels(b.scan(i), low).sum() == 0
    # the roof 13 cm below the sensor takes every beam below about -7 degrees near the
    # car: the same pixels every sweep but for dropouts (1 %); measured 18,251 to
    # 18,289 of 65,536 pixels per sweep (seed 1)
    assert min(counts) > 6000 and max(counts) - min(counts) < 0.05 * max(counts), counts


def test_same_seed_same_messy_drive(tmp):
    args = ["--seed", 7, "--duration", 3, "--with", "lead,crossing,pedestrians,roof"]
    ts.simdrive(tmp / "m1", *args)
    ts.simdrive(tmp / "m2", *args)
    assert (tmp / "m1" / "drive.lcm").read_bytes() == (tmp / "m2" / "drive.lcm").read_bytes()


def test_bad_groups_are_refused(tmp):
    p = ts.simdrive(tmp / "bad1", "--duration", 1, "--no-lidar", "--with", "lead,sheep", check=False)
    assert p.returncode == 2 and "'sheep'" in p.stderr and "lead, crossing, pedestrians, roof" in p.stderr
    p = ts.simdrive(tmp / "bad2", "--mapping", "--no-lidar", "--with", "pedestrians", check=False)
    assert p.returncode == 2 and "mapping" in p.stderr
    p = ts.simdrive(tmp / "bad3", "--site", ROOT / "maps" / "hills", "--duration", 1, "--no-lidar", "--with", "lead",
                    check=False)
    assert p.returncode == 2 and "lead_car" in p.stderr
