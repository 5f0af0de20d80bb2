#!/usr/bin/env python3
"""A street of trees, the case where real LiDAR data is hard and the default site is not:
for bench-localizer-trees.

usage: tree_street.py [--out DIR] [--json OUT.json] [--streets solid,porous,bare,tunnel] [--guesses 40] [--global 10]

The default site without its buildings (trunks, canopies, poles, and parked cars that
differ between the mapping day and the drive day), once with solid canopies and once with
porous ones (simdrive --foliage-depth: a beam into a canopy stops at a random depth inside
it or goes through, anew at every sweep, as real foliage does); and a bare street, without
its trees too (poles, parked cars that changed, traffic: much of what stands above the road
is not in the map, and where the car stops little stands at all); and a tunnel, 272 m of the
south straight between walls 6 m high with nothing else beside the road (the walls and the
road fix every direction but the one along it, and the LiDAR's reach ends before the
portals: a long bridge between parapets, a road in a cutting, or MulRan's keyframes
88-93 are the same to a LiDAR). For each: the map from
the mapping lap at the true poses (as make builds the default map), a 40 s drive (seed 5),
the localizer over the whole drive from the true start (LiDAR alone and with IMU + CAN),
and the starts of bench-localizer-drive on it (bench_starts.py: a prior 3 m / 15 degrees
off, LiDAR alone and fused, moving; no prior). Real MulRan keyframes, for scale: tracking
97.6 % within 0.2 m, starts 70 % from a prior and 50 % with none
(docs/history/localizer-registration.md).
"""
import argparse
import math
import pathlib
import shutil
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import bench_starts as bs  # noqa: E402
import locbench as lb  # noqa: E402

VEHICLE = lb.ROOT / "vehicles" / "prius2017.yaml"
TREES = ("building",)                        # the street of trees: the site without these classes
BARE = ("building", "trunk", "foliage")      # the bare street
# name: (foliage depth m, classes left out, title, folder under --out)
STREETS = {"solid": (0.0, TREES, "street of trees, solid canopies", "solid"),
           "porous": (0.7, TREES, "street of trees, porous canopies 0.7 m", "porous0.7"),
           "bare": (0.0, BARE, "bare street (no buildings, no trees)", "bare"),
           "tunnel": (0.0, (), "tunnel (272 m between walls 6 m high)", "tunnel")}
# The tunnel: the route's south straight from x 45 to 322 m (the lane's points there), walls
# this high outside the sidewalks, every object within this distance of that lane left out
TUNNEL = {"x": (45.0, 322.0), "wall_m": 6.0, "clear_m": 45.0}


def lane_points(route_yaml):
    """The lane centreline's points of a route.yaml (x, y)."""
    import re
    pts = [tuple(map(float, m.groups())) for m in
           (re.match(r"\s*- \[(-?[\d.]+), (-?[\d.]+)\]\s*$", line) for line in open(route_yaml)) if m]
    return np.array(pts)


def tunnel_world(lines, route_yaml):
    """world.yaml's lines with the tunnel: the objects near its lane left out, walls in 4 m
    pieces along both sides outside the sidewalks (the terrain's road half width, kerb and
    sidewalk of the default site)."""
    import re
    P = lane_points(route_yaml)
    x0, x1 = TUNNEL["x"]
    seg = [i for i in range(len(P) - 1) if x0 <= P[i, 0] <= x1 and x0 <= P[i + 1, 0] <= x1 and P[i, 1] < 50]
    a, b = P[seg[0]:seg[-1] + 1], P[seg[0] + 1:seg[-1] + 2]   # the lane's pieces through it

    def near(x, y):
        d = b - a
        t = np.clip(np.einsum("ij,ij->i", np.array([x, y]) - a, d) / np.einsum("ij,ij->i", d, d), 0, 1)
        return np.min(np.hypot(*(a + t[:, None] * d - [x, y]).T)) < TUNNEL["clear_m"]
    out = []
    for line in lines:
        m = re.search(r"center: \[(-?[\d.]+), (-?[\d.]+)", line)
        if "type:" in line and m and near(float(m.group(1)), float(m.group(2))):
            continue
        out.append(line)
    walls = []
    for p, q in zip(a, b):
        u = (q - p) / np.hypot(*(q - p))
        left = np.array([-u[1], u[0]])
        for off in (1.75 + 6.0 + 3.5 + 0.2, 1.75 - 6.0 - 3.5 - 0.2):   # road centre 1.75 m left of the lane
            c = (p + q) / 2 + off * left
            walls.append(f"  - {{type: box, class: building, center: [{c[0]:.2f}, {c[1]:.2f}], "
                         f"yaw_deg: {math.degrees(math.atan2(u[1], u[0])):.2f}, "
                         f"size: [{np.hypot(*(q - p)) + 0.05:.2f}, 0.30, {TUNNEL['wall_m']:.2f}], z0: 0.00}}\n")
    i = max(k for k, line in enumerate(out) if line.startswith("objects:"))
    return out[:i + 1] + walls + out[i + 1:]


def street_site_files(site, drop=TREES, tunnel=False):
    """SITE: the default site's files (site.yaml, route.yaml, world.yaml) without the objects
    of the classes in drop; by default its buildings: trunks, canopies, poles, parked cars
    and traffic stay (bench-mapper's trees drive uses it too). tunnel: with the tunnel."""
    site.mkdir(parents=True, exist_ok=True)
    for name in ("site.yaml", "route.yaml"):
        shutil.copy(lb.ROOT / "maps" / "default" / name, site / name)
    with open(lb.ROOT / "maps" / "default" / "world.yaml") as src:
        lines = [line for line in src if not any(f"class: {c}" in line for c in drop)]
    if tunnel:
        lines = tunnel_world(lines, site / "route.yaml")
    with open(site / "world.yaml", "w") as dst:
        dst.writelines(lines)


def street_map(site, map_pcd, depth, work, drop=TREES, tunnel=False):
    """SITE: street_site_files; MAP_PCD: its map from a mapping lap with this foliage at the
    true poses, as make builds the default map (also tests/test_localizer.py's streets)."""
    street_site_files(site, drop, tunnel)
    lb.sh([lb.BIN / "simdrive", "--mapping", "--quiet", "--site", site, "--foliage-depth", depth, "--out", work])
    lb.sh([lb.BIN / "build-map", "--log", work / "drive.lcm", "--pose-channel", "GROUND_TRUTH",
           "--vehicle", VEHICLE, "--voxel", "0.15", "--quiet", "--out", map_pcd])
    shutil.rmtree(work)


def make_site(out, depth, drop=TREES, tunnel=False):
    """The street as a site folder: map, ground model and tiles."""
    site = out / "site"
    tiles, tool = site / "map.tiles", lb.BIN / "map-tiles"
    if tiles.exists():
        if tiles.stat().st_mtime < tool.stat().st_mtime:    # a tile format this build may not read
            lb.sh([tool, "--map", site / "map.pcd", "--out", tiles, "--quiet"])
        return site
    street_map(site, site / "map.pcd", depth, out / "mapping", drop, tunnel)
    lb.sh([lb.BIN / "build-ground", "--map", site / "map.pcd", "--out", site / "ground.yaml", "--quiet"])
    lb.sh([tool, "--map", site / "map.pcd", "--out", tiles, "--quiet"])
    return site


def track_whole_drive(drive, log, site, gt):
    """The localizer over the whole drive (log: its sensors) from the true pose at its
    first sweep."""
    rows = []
    for mode, keep, label in (("lidar", "LIDAR_SCAN,GROUND_TRUTH", "tracking, LiDAR alone"),
                              ("fused", "LIDAR_SCAN,IMU,VEHICLE_SPEED,GROUND_TRUTH", "tracking, IMU + CAN")):
        inp = drive / f"whole_{mode}.lcm"
        bs.cut(log, inp, 0.5, 39.0, keep)
        g = bs.gt_at(gt, lb.read_channel_times(inp, "LIDAR_SCAN")[0])
        out = drive / f"track_{mode}.lcm"
        lb.run_localizer(inp, out, ["--site", site, "--no-gnss",
                                    f"--initial-pose={g[1]:.3f},{g[2]:.3f},{g[3]:.3f},0,0,{math.degrees(g[4]):.3f}"])
        p = lb.read_poses(out, "POSE")
        trk = p[p[:, 5] == 1]
        eh = bs.horizontal(trk, gt)
        _, et, ey = lb.errors_vs_truth(trk, gt)
        _, z = lb.sigmas_off(out, gt)
        rows.append({"case": label, "poses": len(p), "tracking": len(trk), "lost": int(np.sum(p[:, 5] == 3)),
                     "degraded": int(np.sum(p[:, 5] == 2)), "within_0.2m_pct": 100.0 * float(np.mean(et <= 0.2)),
                     "h_median_m": float(np.median(eh)), "h_p99_m": float(np.percentile(eh, 99)),
                     "h_max_m": float(np.max(eh)), "yaw_p99_deg": float(np.percentile(ey, 99)),
                     "beyond_3_sigma_pct": 100.0 * float(np.mean(z > 3)), "sigmas_max": float(np.max(z))})
        r = rows[-1]
        print(f"  {label:<24} {r['tracking']}/{r['poses']} tracking, {r['degraded']} degraded, {r['lost']} LOST; "
              f"within 0.2 m {r['within_0.2m_pct']:.1f} %, horizontal median {r['h_median_m']:.3f} m, "
              f"p99 {r['h_p99_m']:.3f} m, max {r['h_max_m']:.3f} m, yaw p99 {r['yaw_p99_deg']:.3f} deg; "
              f"beyond 3 sigma {r['beyond_3_sigma_pct']:.1f} % (worst {r['sigmas_max']:.0f} sigma)", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(lb.ROOT / "build" / "bench" / "localizer-trees"))
    ap.add_argument("--json", default=str(lb.ROOT / "build" / "bench" / "localizer-trees.json"))
    ap.add_argument("--streets", default="solid,porous,bare,tunnel", help="streets to run (%(default)s)")
    ap.add_argument("--guesses", type=int, default=40)
    ap.add_argument("--global", dest="n_global", type=int, default=10)
    a = ap.parse_args()
    result = []
    for street in a.streets.split(","):
        if street not in STREETS:
            sys.exit(f"tree_street.py: --streets: unknown street {street!r} (one of {', '.join(STREETS)})")
        depth, drop, name, folder = STREETS[street]
        out = pathlib.Path(a.out) / folder
        print(f"== {name}: site, map and drive in {out}", flush=True)
        site = make_site(out, depth, drop, tunnel=street == "tunnel")
        drive = out / "drive5"
        # with VEHICLE_SPEED decoded from its CAN frames, as on the car
        log = lb.make_drive(drive, 5, "normal", 40, extra=["--foliage-depth", depth], site=site)
        gt = lb.read_poses(drive / "drive.lcm", "GROUND_TRUTH")
        tracking = track_whole_drive(drive, log, site, gt)
        starts = bs.run_starts([(drive, log)], site, n_guesses=a.guesses, n_frames=10, n_gnss=0,
                               n_global=a.n_global, seconds=6.0, jobs=2)
        result.append({"street": street, "canopies": name, "foliage_depth_m": depth, "left_out": list(drop),
                       "tracking": tracking, "starts": [s for s in starts if s["starts"] > 0]})
    bs.write_json(pathlib.Path(a.json), result)
    print(f"written {a.json}")


if __name__ == "__main__":
    main()
