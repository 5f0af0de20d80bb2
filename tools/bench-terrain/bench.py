#!/usr/bin/env python3
"""Terrain benchmark (make bench-terrain); writes build/bench/terrain.json.

1. Ground model accuracy, per site with terrain: the ground model make built from
   the prior map (maps/SITE/ground.yaml, tools/build-ground) against the simulator's
   true height field (simdrive --terrain-out) on the true drivable and walkable
   cells: |error| median, p95, max, and the share of those cells the model covers.
   Baseline: the flat ground z = 0 every figure used before terrain. Target: p95 <= 5 cm.
2. simdrive's wall and CPU time for a 60 s drive (LiDAR on), on hills (terrain),
   on default (gentle relief; the baseline, what every drive before the hills cost) and
   on default with the messier world
   (--with lead,crossing,pedestrians,roof), one run each, same seed.
   Target: <= 30 s wall on 2 cores.

3. (--localizer) the current localizer on the hills: simdrive drives (3 profiles x
   the given seeds, 30 s, drive day) + VEHICLE_SPEED, replayed through the localizer
   started by GNSS, scored against GROUND_TRUTH like make bench-localizer-drive
   (targets: median <= 0.03 m, p99 <= 0.15 m, yaw p99 <= 0.3 deg, no LOST).
   --loc-sites NAME[:GROUP+GROUP...] drives each site with those simdrive --with groups,
   e.g. default:lead+crossing+pedestrians+roof (the messier world).

4. (--twin) lab vs road on each of --sites with the localizer's POSE on the road: a 110 s simdrive
   drive (normal profile) replayed through the localizer, the lab twin offline (proceed
   2 s after each stop), the director on each with every cw*.yaml scenario. Per
   scenario: whether the SCENARIO_EVENT sequences (kind, id, agent) are identical, and
   the distance between the car's positions where each trigger fired on the two
   platforms. Baseline: the road side on GROUND_TRUTH. Target: identical, <= 0.2 m.

    tools/bench-terrain/bench.py [--sites hills,default] [--work DIR] [--localizer --loc-seeds 1,2 --loc-sites hills]
                                 [--twin --twin-seed 3]
"""
import argparse
import atexit
import json
import pathlib
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[2]
BIN = ROOT / "build" / "bin"


def read_ground(yaml_path):
    """A ground model (docs/sites.md) as (x0, y0, cell, heights[ny, nx] with NaN unknown)."""
    y = yaml.safe_load(open(yaml_path))
    raw = open(pathlib.Path(yaml_path).parent / y["file"], "rb").read()
    if "block" in y:    # the blocked file: records of bx, by, B x B values, checksum
        b, w, h = y["block"], y["width"], y["height"]
        nbx, nby = -(-w // b), -(-h // b)
        v = np.zeros((nby * b, nbx * b), dtype=np.uint16)
        rec = np.frombuffer(raw, dtype=np.uint8, offset=8).reshape(y["blocks"], 8 + 2 * b * b + 8)
        for r in rec:
            bx, by = r[:8].view("<i4")
            v[by * b:(by + 1) * b, bx * b:(bx + 1) * b] = r[8:8 + 2 * b * b].view("<u2").reshape(b, b)
        v = v[:h, :w].astype(np.float64)
        return y["origin_x"], y["origin_y"], y["cell_m"], np.where(v > 0, y["z0_m"] + (v - 1) * y["scale_m"], np.nan)
    # header: P5, comments, width height, maxval, one whitespace
    tokens, i = [], 2
    while len(tokens) < 3:
        while raw[i:i + 1].isspace():
            i += 1
        if raw[i:i + 1] == b"#":
            while raw[i:i + 1] != b"\n":
                i += 1
            continue
        j = i
        while not raw[j:j + 1].isspace():
            j += 1
        tokens.append(int(raw[i:j]))
        i = j
    w, h, _ = tokens
    v = np.frombuffer(raw[i + 1:], dtype=">u2").reshape(h, w).astype(np.float64)
    z = np.where(v > 0, y["z0_m"] + (v - 1) * y["scale_m"], np.nan)
    return y["origin_x"], y["origin_y"], y["cell_m"], z


def sample(model, x, y):
    """Bilinear heights of a model at points (NaN where a corner is unknown or outside)."""
    x0, y0, c, z = model
    fx, fy = (x - x0) / c, (y - y0) / c
    i, j = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ok = (i >= 0) & (j >= 0) & (i < z.shape[1] - 1) & (j < z.shape[0] - 1)
    out = np.full(x.shape, np.nan)
    i, j, u, v = i[ok], j[ok], (fx - np.floor(fx))[ok], (fy - np.floor(fy))[ok]
    out[ok] = ((1 - v) * ((1 - u) * z[j, i] + u * z[j, i + 1]) + v * ((1 - u) * z[j + 1, i] + u * z[j + 1, i + 1]))
    return out


def ground_accuracy(site, work):
    truth_path = work / f"{site}-truth.yaml"
    subprocess.run([BIN / "simdrive", "--site", ROOT / "maps" / site, "--terrain-out", truth_path], check=True)
    truth = read_ground(truth_path)
    model = read_ground(ROOT / "maps" / site / "ground.yaml")
    x0, y0, c, zt = truth
    jj, ii = np.nonzero(~np.isnan(zt))
    x, y, ztrue = x0 + ii * c, y0 + jj * c, zt[jj, ii]
    # cells of the truth whose four corners are walkable (a cell, not just a corner)
    zm = sample(model, x, y)
    cover = ~np.isnan(zm)
    err = np.abs(zm[cover] - ztrue[cover])
    flat = np.abs(ztrue)
    row = {"site": site, "cells": int(len(ztrue)), "covered": float(cover.mean()),
           "model_median_m": float(np.median(err)), "model_p95_m": float(np.percentile(err, 95)),
           "model_max_m": float(err.max()),
           "flat_median_m": float(np.median(flat)), "flat_p95_m": float(np.percentile(flat, 95))}
    return row


def drive_time(site, work, groups=""):
    out = work / f"drive-{site}{'-messy' if groups else ''}"
    t0 = time.monotonic()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([BIN / "simdrive", "--site", ROOT / "maps" / site, "--out", out, "--duration", "60",
                    "--seed", "3", "--quiet"] + (["--with", groups] if groups else []), check=True)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"site": site + (" +" + groups.replace(",", "+") if groups else ""), "wall_s": time.monotonic() - t0,
            "cpu_s": (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)}


def localizer_runs(spec, seeds, work, duration=30):
    site, _, groups = spec.partition(":")
    groups = groups.replace("+", ",")
    sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
    import locbench as lb
    rows = []
    for prof in ("cautious", "normal", "aggressive"):
        for seed in seeds:
            d = work / f"loc-{site}{'-' + groups.replace(',', '-') if groups else ''}-{prof}-{seed}"
            merged = d / "input.lcm"
            if not lb.cached(merged, ROOT / "maps" / site):
                lb.sh([BIN / "simdrive", "--site", ROOT / "maps" / site, "--out", d, "--seed", seed,
                       "--speed-profile", prof, "--duration", duration, "--quiet"] + (["--with", groups] if groups else []))
                lb.sh([BIN / "can", "--replay", d / "drive.lcm", "--out", d / "speed.lcm"])
                lb.sh([BIN / "log-merge", "--quiet", "--out", merged, d / "drive.lcm", d / "speed.lcm"])
            out, stats = d / "out.lcm", d / "stats.csv"
            p = lb.run_localizer(merged, out, ["--site", ROOT / "maps" / site], stats)
            if p.returncode != 0:
                rows.append({"site": spec, "profile": prof, "seed": seed, "error": p.stderr[-300:]})
                continue
            r = lb.score_run(d / "drive.lcm", out, stats)
            rows.append({"site": spec, "profile": prof, "seed": seed,
                         **{k: r.get(k) for k in ("t_median", "t_p99", "t_max", "yaw_p99", "lost_after_tracking",
                                                  "first_tracking_s")}})
    return rows


def twin_run(site, seed, work):
    sys.path.insert(0, str(ROOT / "modules" / "localizer" / "bench"))
    sys.path.insert(0, str(ROOT / "build" / "python"))
    import lcm
    import locbench as lb
    import portobello
    sdir = ROOT / "maps" / site
    d = work / f"twin-{site}-{seed}"
    merged, out, road = d / "input.lcm", d / "loc.lcm", d / "road.lcm"
    if not lb.cached(road, sdir):
        lb.sh([BIN / "simdrive", "--site", sdir, "--out", d, "--seed", seed, "--duration", 110, "--quiet"])
        lb.sh([BIN / "can", "--replay", d / "drive.lcm", "--out", d / "speed.lcm"])
        lb.sh([BIN / "log-merge", "--quiet", "--out", merged, d / "drive.lcm", d / "speed.lcm"])
        p = lb.run_localizer(merged, out, ["--site", sdir])
        if p.returncode != 0:
            raise SystemExit(f"localizer failed: {p.stderr[-500:]}")
        lb.sh([BIN / "log-merge", "--quiet", "--out", road, d / "drive.lcm", out])
    lab = d / "lab.lcm"
    if not lb.cached(lab, sdir):
        lb.sh([BIN / "lab_vehicle", "--site", sdir, "--out", lab, "--auto-proceed", 2.0, "--duration", 115])

    def events(log):
        return [portobello.scenario_event_t.decode(ev.data) for ev in lcm.EventLog(str(log), "r")
                if ev.channel == "SCENARIO_EVENT"]
    rows = []
    for f in sorted((sdir / "scenarios").glob("cw*.yaml")):
        seqs, where = {}, {}
        for side, log, ch in (("lab", lab, "POSE"), ("road", road, "POSE"), ("pred", road, "POSE_PREDICTED"),
                              ("truth", d / "drive.lcm", "GROUND_TRUTH")):
            o = d / f"{side}_{f.stem}.lcm"
            lb.sh([BIN / "director", "--site", sdir, "--scenario", f, "--replay", log, "--out", o, "--pose-channel", ch])
            ev = events(o)
            seqs[side] = [(e.kind, e.event_id, e.agent_id) for e in ev]
            where[side] = {e.event_id: np.array(e.vehicle.position[:2]) for e in ev if e.kind == "trigger"}
        gap = lambda a, b, ids=None: max([float(np.hypot(*(where[a][k] - where[b][k]))) for k in where[a]
                                          if k in where[b] and (ids is None or k in ids)] or [np.nan])
        # triggers placed by a volume alone (enter) vs those that depend on how each car stops and sets off
        enter = {t["id"] for t in yaml.safe_load(open(f))["triggers"] if t["when"].get("type") == "enter"}
        rows.append({"site": site, "scenario": f.stem, "triggers": len(where["lab"]),
                     "same_road": seqs["lab"] == seqs["road"], "same_truth": seqs["lab"] == seqs["truth"],
                     "same_pred": seqs["lab"] == seqs["pred"], "max_trigger_gap_pred_m": gap("lab", "pred"),
                     "max_trigger_gap_road_m": gap("lab", "road"), "max_trigger_gap_truth_m": gap("lab", "truth"),
                     "max_enter_gap_road_m": gap("lab", "road", enter), "max_enter_gap_pred_m": gap("lab", "pred", enter),
                     "per_trigger_pred_m": {k: float(np.hypot(*(where["lab"][k] - where["pred"][k])))
                                            for k in where["lab"] if k in where["pred"]},
                     "per_trigger_road_m": {k: float(np.hypot(*(where["lab"][k] - where["road"][k])))
                                            for k in where["lab"] if k in where["road"]}})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sites", default="hills,default")
    ap.add_argument("--work")
    ap.add_argument("--localizer", action="store_true", help="also run the localizer on the sites' drives")
    ap.add_argument("--loc-seeds", default="1")
    ap.add_argument("--loc-sites", default=None, help="sites for --localizer (default: --sites), NAME[:GROUP+GROUP]")
    ap.add_argument("--skip-ground", action="store_true")
    ap.add_argument("--twin", action="store_true", help="lab twin vs road (localizer POSE) on each of --sites")
    ap.add_argument("--twin-seed", type=int, default=3)
    args = ap.parse_args()
    work = pathlib.Path(args.work or tempfile.mkdtemp(prefix="bench-terrain-"))
    if not args.work:   # its drives are 0.6 GB a run: a scratch folder goes when the run ends
        atexit.register(shutil.rmtree, work, True)
    work.mkdir(parents=True, exist_ok=True)
    result = {}
    if args.localizer:
        loc = []
        for site in (args.loc_sites or args.sites).split(","):
            loc += localizer_runs(site, [int(x) for x in args.loc_seeds.split(",")], work)
        print("current localizer (GNSS start) vs GROUND_TRUTH; targets: median <= 0.03 m, p99 <= 0.15 m, "
              "yaw p99 <= 0.3 deg, no LOST")
        print(f"{'site':8} {'profile':11} {'seed':>4} {'med m':>7} {'p99 m':>7} {'max m':>7} {'yaw99':>6} {'LOST':>5} {'init s':>6}")
        f = lambda v, n=3: "-" if v is None or (isinstance(v, float) and v != v) else f"{v:.{n}f}"
        for r in loc:
            if "error" in r:
                print(f"{r['site']:8} {r['profile']:11} {r['seed']:>4} localizer failed: {r['error']}")
                continue
            print(f"{r['site']:8} {r['profile']:11} {r['seed']:>4} {f(r['t_median']):>7} {f(r['t_p99']):>7} "
                  f"{f(r['t_max']):>7} {f(r['yaw_p99']):>6} {str(r['lost_after_tracking']):>5} {f(r['first_tracking_s'], 1):>6}")
        result["localizer"] = loc
        print()
    if args.twin:
        tw = []
        for site in args.sites.split(","):
            tw += twin_run(site, args.twin_seed, work)
        print(f"lab twin vs road (seed {args.twin_seed}, 110 s, normal): SCENARIO_EVENT sequences and the "
              f"car's position at each trigger; road = the localizer's POSE (10 Hz, as stacks/road.yaml) or "
              f"POSE_PREDICTED (200 Hz); baseline = GROUND_TRUTH (100 Hz). Target: same, <= 0.2 m")
        print("gap m: the largest distance over all triggers; enter m: over the enter (volume) triggers alone")
        print(f"{'site':8} {'scenario':22} {'trig':>4} | {'POSE same':>9} {'gap m':>6} {'enter m':>7} | "
              f"{'PREDICTED same':>14} {'gap m':>6} {'enter m':>7} | {'GT same':>7} {'gap m':>6}")
        row = lambda name, n, r: print(
            f"{name:31} {n:4d} | {str(r['same_road']):>9} {r['max_trigger_gap_road_m']:6.3f} {r['max_enter_gap_road_m']:7.3f} | "
            f"{str(r['same_pred']):>14} {r['max_trigger_gap_pred_m']:6.3f} {r['max_enter_gap_pred_m']:7.3f} | "
            f"{str(r['same_truth']):>7} {r['max_trigger_gap_truth_m']:6.3f}")
        for r in tw:
            row(f"{r['site']:8} {r['scenario']}", r["triggers"], r)
        row("all", sum(r["triggers"] for r in tw),
            {k: (all(r[k] for r in tw) if k.startswith("same") else max(r[k] for r in tw))
             for k in tw[0] if k.startswith("same") or k.startswith("max_")})
        result["twin"] = tw
        print()
    if args.skip_ground:
        (ROOT / "build" / "bench").mkdir(parents=True, exist_ok=True)
        out = ROOT / "build" / "bench" / ("terrain-twin.json" if args.twin and not args.localizer else "terrain-localizer.json")
        out.write_text(json.dumps(result, indent=1, default=str))
        print(f"wrote {out}")
        return 0
    rows = [ground_accuracy(s, work) for s in args.sites.split(",")]
    print("ground model vs true height field (drivable + walkable cells); baseline: flat z = 0")
    print(f"{'site':8} {'cells':>9} {'covered':>8} {'med cm':>7} {'p95 cm':>7} {'max cm':>7} | {'flat med':>8} {'flat p95':>8}")
    for r in rows:
        print(f"{r['site']:8} {r['cells']:9d} {100 * r['covered']:7.1f}% {100 * r['model_median_m']:7.2f} "
              f"{100 * r['model_p95_m']:7.2f} {100 * r['model_max_m']:7.1f} | {100 * r['flat_median_m']:8.1f} "
              f"{100 * r['flat_p95_m']:8.1f}")
    times = [drive_time("hills", work), drive_time("default", work),
             drive_time("default", work, "lead,crossing,pedestrians,roof")]
    print("\nsimdrive, 60 s drive with LiDAR (seed 3); baseline: default site (gentle relief)")
    print(f"{'site':42} {'wall s':>7} {'cpu s':>7}")
    for t in times:
        print(f"{t['site']:42} {t['wall_s']:7.1f} {t['cpu_s']:7.1f}")
    print(f"ratio hills/default: wall {times[0]['wall_s'] / times[1]['wall_s']:.2f}, cpu {times[0]['cpu_s'] / times[1]['cpu_s']:.2f}")
    (ROOT / "build" / "bench").mkdir(parents=True, exist_ok=True)
    out = ROOT / "build" / "bench" / "terrain.json"
    out.write_text(json.dumps({"ground": rows, "simdrive_60s": times, **result}, indent=1, default=str))
    print(f"\nwrote {out}")


if __name__ == "__main__":
    sys.exit(main())
