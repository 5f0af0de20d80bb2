#!/usr/bin/env python3
"""make bench-occlusion: cost and agreement of the occlusion module on a 10-minute
simulated drive with OCCLUSION_TRUTH, against stock OctoMap on the same sweeps.

1. simdrive --scenario maps/default/scenes/occlusion_scene.yaml --head, 600 s (once; kept in build/bench/occlusion/drive)
2. occlusion-bench (one thread, thread CPU time): ours on every sweep (integrate; query of
   100 agents), REPEATS runs in all; stock insertPointCloud + castRay on sweeps STOCK_FROM..
   (after 10 warm-up) as the first run wrote them, REPEATS runs, each in a process of its
   own (so neither method runs in caches or a heap the other just used). The ratio to stock
   sets the median of stock's run medians against the median of ours' run medians on those
   same sweeps (and is shown against every sweep). A fixed work timed as the sweeps are gives
   the host's noise, so the p99 can be read (a sweep's own cost is the least of its runs; the
   same work's p99 over its median is the host's)
3. agreement with the truth: ours over the whole drive; ours and stock on the stock sweeps
4. real sweeps: the HDL-32E pair of tests/data (two outdoor sweeps 0.5 m apart), ours and
   stock in turn on the same points; both answer samples whose state the first sweep's own
   beams tell (1 m behind a return: hidden, 1 m before it: visible), with the sensor's
   beam gaps (HDL-32E: rings 1.33 deg apart, columns 0.167 deg) and with the config's
Prints a table; writes build/bench/occlusion.json.
"""
import json
import math
import os
import statistics
import subprocess
import sys

TOP = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))
BUILD = os.path.join(TOP, "build")
sys.path.insert(0, os.path.join(BUILD, "python"))
sys.path.insert(0, os.path.dirname(__file__))
from occ_agreement import CAUSES, agreement, read_states, read_truth  # noqa: E402

DURATION = int(os.environ.get("OCC_BENCH_DURATION", "600"))
STOCK_FROM = int(os.environ.get("OCC_BENCH_STOCK_FROM", "300"))
STOCK_COUNT = int(os.environ.get("OCC_BENCH_STOCK_COUNT", "30"))
REPEATS = int(os.environ.get("OCC_BENCH_REPEATS", "3"))
P99_TARGET_MS = 30
HDL32 = os.path.join(TOP, "tests", "data", "lidar_pair_hdl32")


def pct(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, max(0, math.ceil(q * len(v)) - 1))]


def host_noise(times, median_ms):
    """Per-sweep times of the runs of the same sweeps, and the same fixed work timed as
    often: the host's noise beside the sweeps' own cost."""
    runs = []
    for t in times:
        with open(t) as f:
            runs.append([float(x) for x in f])
    if len({len(r) for r in runs}) != 1:
        sys.exit(f"bench-occlusion: the runs timed different numbers of sweeps: {[len(r) for r in runs]}")
    least = [min(v) for v in zip(*runs)]
    slow = [sum(1 for x in r if x > P99_TARGET_MS) for r in runs]
    slow_every_run = sum(1 for v in zip(*runs) if min(v) > P99_TARGET_MS)
    r = subprocess.run([os.path.join(BUILD, "bin", "occlusion-bench"), "--noise", str(len(runs[0]) // 2),
                        "--noise-ms", f"{median_ms:.3f}"], check=True, stdout=subprocess.PIPE, text=True)
    work = json.loads(r.stdout)
    return dict(runs=len(runs), p50_per_run=[pct(r_, 0.5) for r_ in runs], p99_per_run=[pct(r_, 0.99) for r_ in runs],
                over_target_per_run=slow, over_target_every_run=slow_every_run,
                least_of_runs_p50=pct(least, 0.5), least_of_runs_p99=pct(least, 0.99), fixed_work=work)


def main():
    d = os.path.join(BUILD, "bench", "occlusion")
    drive = os.path.join(d, "drive", "drive.lcm")
    stamp = os.path.join(d, "drive", f"done-{DURATION}")
    scene = os.path.join(TOP, "maps", "default", "scenes", "occlusion_scene.yaml")
    # made again when simdrive or the site changed since (a cached flat drive would be
    # scored against the site's relief)
    inputs = [os.path.join(BUILD, "bin", "simdrive"), scene] + \
        [os.path.join(TOP, "maps", "default", f) for f in ("site.yaml", "route.yaml", "world.yaml")]
    if not os.path.exists(stamp) or any(os.path.getmtime(i) > os.path.getmtime(stamp) for i in inputs):
        print(f"bench-occlusion: simulating a {DURATION} s drive with agents and OCCLUSION_TRUTH (once) ...", flush=True)
        subprocess.run([os.path.join(BUILD, "bin", "simdrive"), "--out", os.path.dirname(drive), "--duration",
                        str(DURATION), "--seed", "3", "--scenario", scene, "--head", "--quiet"], check=True)
        open(stamp, "w").close()
    out = os.path.join(d, "bench_out.lcm")
    jobs = os.path.join(d, "stock_sweeps.bin")
    stock_out = os.path.join(d, "bench_out_stock.lcm")
    print("bench-occlusion: ours on every sweep ...", flush=True)
    times = [os.path.join(d, f"integrate_ms_run{k}.txt") for k in range(REPEATS)]
    r = subprocess.run([os.path.join(BUILD, "bin", "occlusion-bench"), "--log", drive, "--out", out,
                        "--stock-from", str(STOCK_FROM), "--stock-count", str(STOCK_COUNT), "--stock-out", jobs,
                        "--times", times[0]], check=True, stdout=subprocess.PIPE, text=True)
    cost = json.loads(r.stdout)
    spare = os.path.join(d, "bench_out_rerun.lcm")
    ours_same = [cost["integrate_ms_stock_sweeps_p50"]]
    for k in range(1, REPEATS):
        print(f"bench-occlusion: ours alone again, run {k + 1} of {REPEATS} (the host's noise) ...", flush=True)
        r = subprocess.run([os.path.join(BUILD, "bin", "occlusion-bench"), "--log", drive, "--out", spare,
                            "--stock-from", str(STOCK_FROM), "--stock-count", str(STOCK_COUNT), "--times", times[k]],
                           check=True, stdout=subprocess.PIPE, text=True)
        ours_same.append(json.loads(r.stdout)["integrate_ms_stock_sweeps_p50"])
    if os.path.exists(spare):
        os.remove(spare)
    # stock as often as ours, each run a process of its own on the same sweeps (its times
    # move by a fifth from run to run): the ratio sets the median of each's run medians
    stock_runs = []
    for k in range(REPEATS):
        print(f"bench-occlusion: stock OctoMap alone on {STOCK_COUNT} of those sweeps from {STOCK_FROM}, run {k + 1} "
              f"of {REPEATS} (about 1 s a sweep) ...", flush=True)
        r = subprocess.run([os.path.join(BUILD, "bin", "occlusion-bench"), "--stock-in", jobs, "--out",
                            stock_out if k == 0 else spare], check=True, stdout=subprocess.PIPE, text=True)
        stock_runs.append(json.loads(r.stdout))
        if k and read_states(spare, "OCCLUSION_STOCK") != read_states(stock_out, "OCCLUSION_STOCK"):
            sys.exit("bench-occlusion: stock OctoMap answered differently in two runs of the same sweeps")
    if os.path.exists(spare):
        os.remove(spare)
    os.remove(jobs)
    cost["integrate_ms_stock_sweeps_p50_per_run"] = ours_same
    cost["integrate_ms_stock_sweeps_p50"] = statistics.median(ours_same)
    for key in ("stock_insert_ms_p50", "stock_insert_ms_p99", "stock_query100_ms_p50", "stock_us_per_ray_p50", "stock_rss_max_kb"):
        cost[key + "_per_run"] = [x[key] for x in stock_runs]
        cost[key] = statistics.median(cost[key + "_per_run"])
    cost["stock_sweeps"] = stock_runs[0]["stock_sweeps"]
    noise = host_noise(times, cost["integrate_ms_p50"])
    print("bench-occlusion: agreement with the truth ...", flush=True)
    truth = read_truth(drive)
    ours = read_states(out, "OCCLUSION")
    stock = read_states(stock_out, "OCCLUSION_STOCK")
    ours_all = agreement(truth, ours)
    stock_times = set(stock)
    ours_sub = agreement(truth, ours, utimes=stock_times)
    stock_sub = agreement(truth, stock, utimes=stock_times)
    print("bench-occlusion: real sweeps (HDL-32E pair) ...", flush=True)
    real = {}
    for name, gaps in (("sensor_gaps", ["--ring-gap-deg", "1.333", "--col-gap-deg", "0.1667"]), ("config_gaps", [])):
        r = subprocess.run([os.path.join(BUILD, "bin", "occlusion-bench"), "--real", HDL32] + gaps,
                           check=True, stdout=subprocess.PIPE, text=True)
        real[name] = json.loads(r.stdout)
    mem = cost.pop("memory_per_minute")
    memory = [dict(sweep=mem[i], leaves=mem[i + 1], map_bytes=mem[i + 2], rss_kb=mem[i + 3]) for i in range(0, len(mem), 4)]
    res = dict(cost=cost, host_noise=noise, agreement_ours_drive=ours_all, agreement_ours_stock_sweeps=ours_sub,
               agreement_stock=stock_sub, memory=memory, duration_s=DURATION, stock_from=STOCK_FROM,
               stock_count=STOCK_COUNT, real_hdl32=real)
    with open(os.path.join(BUILD, "bench", "occlusion.json"), "w") as f:
        json.dump(res, f, indent=1)

    c = cost
    print()
    print("occlusion, one thread (thread CPU time)          ours          stock OctoMap   target")
    print(f"integrate a 64x1024 sweep, median (ms)       {c['integrate_ms_p50']:9.2f}     {c['stock_insert_ms_p50']:12.1f}   <= 15")
    print(f"integrate, p99 (ms)                          {c['integrate_ms_p99']:9.2f}     {c['stock_insert_ms_p99']:12.1f}   <= 30")
    print(f"  (ours: run 1, every sweep; stock: the median of its {REPEATS} runs on its {STOCK_COUNT} sweeps)")
    print(f"  on the {STOCK_COUNT} sweeps stock integrates, median of {REPEATS} runs {c['integrate_ms_stock_sweeps_p50']:5.2f}"
          f"     {c['stock_insert_ms_p50']:12.1f}")
    print(f"    each run's median (ms)                   " + ", ".join(f"{x:.2f}" for x in c["integrate_ms_stock_sweeps_p50_per_run"]) +
          "   " + ", ".join(f"{x:.1f}" for x in c["stock_insert_ms_p50_per_run"]))
    print(f"  stock / ours, the same {STOCK_COUNT} sweeps (median)  {c['stock_insert_ms_p50'] / c['integrate_ms_stock_sweeps_p50']:6.0f}x"
          f"                  about 100x  (against ours on every sweep: "
          f"{c['stock_insert_ms_p50'] / c['integrate_ms_p50']:.0f}x)")
    n = noise
    w = n["fixed_work"]
    print(f"  p99 of each run's sweeps, {n['runs']} runs         " + ", ".join(f"{x:.2f}" for x in n["p99_per_run"]) +
          f"; sweeps over {P99_TARGET_MS} ms: " + ", ".join(str(x) for x in n["over_target_per_run"]) +
          f", in every run: {n['over_target_every_run']}")
    print(f"  p99 of each sweep's least time             {n['least_of_runs_p99']:9.2f}                      <= {P99_TARGET_MS}"
          f" (the sweeps' own cost; median {n['least_of_runs_p50']:.2f})")
    print(f"  the host: a fixed work timed {w['runs']} times: median {w['work_ms_p50']:.2f} ms, p99 {w['work_ms_p99']:.2f} ms"
          f" ({w['work_ms_p99'] / w['work_ms_p50']:.1f} x its median; the same work every time)")
    print(f"query 100 agents, median (ms)                {c['query100_ms_p50']:9.3f}     {c['stock_query100_ms_p50']:12.3f}   <= 1")
    print(f"  per ray (us)                               {c['ours_us_per_ray_p50']:9.3f}     {c['stock_us_per_ray_p50']:12.3f}")
    print(f"sweeps                                       {c['sweeps']:9d}     {c['stock_sweeps']:12d}")
    print()

    def row(name, a):
        cf = a["confusion"]
        print(f"{name:34s} {a['samples']:8d} {100 * a['agreement']:7.2f}% {100 * a['visible_when_hidden_of_hidden']:7.2f}% "
              f"{100 * a['visible_when_hidden_of_all']:7.3f}% {100 * a['unknown_fraction']:6.2f}% "
              f"{100 * a['changes_within_one_sweep']:6.1f}% ({a['state_changes']})")
        return cf
    print("agreement with OCCLUSION_TRUTH (samples within 45 m)  samples  agree  vis|hid  vis|hid  unknown  changes<=1 sweep")
    print("                                                                (of hid) (of all)")
    cf = row("ours, whole drive", ours_all)
    row(f"ours, the {STOCK_COUNT} stock sweeps", ours_sub)
    row(f"stock OctoMap, same sweeps", stock_sub)
    print("targets: agree >= 97%, visible when truly hidden <= 1%, every change within one sweep")
    a = ours_all
    print()
    print(f"truth changes (visible <-> hidden), ours, whole drive: {a['state_changes']}, followed within one sweep "
          f"{100 * a['changes_within_one_sweep']:.1f}% (raw); of the {a['changes_followable']} whose new state lasts "
          f"two sweeps or more and whose sample stays in range: {100 * a['followable_within_one_sweep']:.1f}%")
    print(f"  not followed, by cause          {'to visible':>10s} {'to hidden':>10s}")
    for cause in CAUSES:
        n = a["changes_not_followed"][cause]
        print(f"  {cause:30s} {n['to_visible']:10d} {n['to_hidden']:10d}")
    print("  (truth_flicker: the truth's new state lasts one sweep; sample_leaves: no next sweep in range;"
          " late_by_1: two sweeps after the truth)")
    print()
    print("confusion, ours, whole drive (rows truth, columns module)")
    print(f"{'':16s}{'visible':>10s}{'hidden':>10s}{'unknown':>10s}")
    for t in ("visible", "hidden"):
        r_ = cf[f"truth_{t}"]
        print(f"{t:16s}{r_['module_visible']:10d}{r_['module_hidden']:10d}{r_['module_unknown']:10d}")
    print()
    print("memory over the drive: minute, map leaves, map MB, process RSS MB")
    for m in memory:
        print(f"  {m['sweep'] / 600:4.0f}  {m['leaves']:9d}  {m['map_bytes'] / 1e6:7.1f}  {m['rss_kb'] / 1e3:7.1f}")
    print(f"  process RSS: max {c['rss_max_kb'] / 1e3:.1f} MB, end {c['rss_end_kb'] / 1e3:.1f} MB "
          f"(stock's own process: peak {c['stock_rss_max_kb'] / 1e3:.1f} MB)")
    print()
    print("real sweeps, HDL-32E pair (tests/data; about 64,000 returns each, most within 15 m), one thread:")
    print(f"{'':34s}{'integrate ms':>13s}{'agree':>8s}{'vis|hid':>9s}{'hid|vis':>9s}{'unknown':>9s}  samples")

    def real_row(name, ms, c):
        tv, th = c["truth_visible"], c["truth_hidden"]
        n = sum(tv) + sum(th)
        print(f"{name:34s}{ms:13.2f}{100 * (tv[0] + th[1]) / n:7.2f}%{100 * th[0] / sum(th):8.2f}%"
              f"{100 * tv[1] / sum(tv):8.2f}%{100 * (tv[2] + th[2]) / n:8.2f}%  {n}")
    g = real["sensor_gaps"]
    real_row("ours, the sensor's beam gaps", g["ours_integrate_ms_p50"], g["ours"])
    real_row("ours, the config's (64 x 1024)", real["config_gaps"]["ours_integrate_ms_p50"], real["config_gaps"]["ours"])
    real_row("stock OctoMap", g["stock_insert_ms_p50"], g["stock"])
    print(f"  stock / ours (median): {g['stock_insert_ms_p50'] / g['ours_integrate_ms_p50']:.0f}x  "
          "(vis|hid: visible where hidden, of hidden; hid|vis: hidden where visible, of visible)")
    print(f"\nwritten: {os.path.join(BUILD, 'bench', 'occlusion.json')}")


if __name__ == "__main__":
    main()
