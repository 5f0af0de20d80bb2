#!/usr/bin/env python3
"""make bench-localizer-memory: the localizer's resident memory on the default site, with
the map paged in tiles (the default: tiles within 120 m of the car) against the same
binary holding every tile (--map-radius 1000000: the whole map), and over a long replay: a full-lap simdrive drive (seed 4, aggressive, 232 s, with VEHICLE_SPEED)
played LOOPS times back to back (default 16 laps, 62 min of driving). Each lap's copy has its
message times shifted by the lap's length so time runs on; the looped log streams through a
FIFO (nothing that large is written to disc). RSS (VmRSS of /proc/PID/status) is sampled
every 0.5 s wall time. One lap is also replayed to files with both maps and the POSE
messages compared byte for byte (paging must not change a pose). The replay runs as fast
as the localizer takes it (faster than real time when it keeps up: the wall time is
printed).

Prints a table and writes build/bench/localizer-memory/results.json.
usage: bench_memory.py [--loops N]
"""
import argparse
import json
import os
import pathlib
import struct
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import locbench  # noqa: E402
from locbench import BIN, ROOT  # noqa: E402

OUT = ROOT / "build" / "bench" / "localizer-memory"
SITE = ROOT / "maps" / "default"
SYNC = 0xEDA1DA01
# channels whose message starts (after the 8-byte LCM fingerprint) with int64 utime
TIMED = {b"LIDAR_SCAN", b"IMU", b"GNSS_FIX", b"VEHICLE_SPEED", b"CAN_FRAME", b"GROUND_TRUTH"}


def read_events(path):
    """Raw events (timestamp, channel, payload) of an LCM event log, TIMED channels only."""
    data = pathlib.Path(path).read_bytes()
    off, evs = 0, []
    while off + 28 <= len(data):
        sync, _num, ts, chlen, dlen = struct.unpack_from(">IqqII", data, off)
        if sync != SYNC:
            raise RuntimeError(f"{path}: byte {off}: bad sync word")
        ch = data[off + 28:off + 28 + chlen]
        payload = data[off + 28 + chlen:off + 28 + chlen + dlen]
        off += 28 + chlen + dlen
        if ch in TIMED and len(payload) >= 16:
            evs.append((ts, ch, payload))
    return evs


def write_loops(evs, loops, fifo, progress):
    """Writes the events `loops` times with times shifted by one lap each, into fifo."""
    t0, t1 = evs[0][0], evs[-1][0]
    lap_us = t1 - t0 + 100000
    num = 0
    with open(fifo, "wb", buffering=1 << 20) as f:
        for k in range(loops):
            progress["lap"] = k
            shift = k * lap_us
            for ts, ch, payload in evs:
                ut = struct.unpack_from(">q", payload, 8)[0]
                p = payload[:8] + struct.pack(">q", ut + shift) + payload[16:]
                f.write(struct.pack(">IqqII", SYNC, num, ts + shift, len(ch), len(p)) + ch + p)
                num += 1
    progress["lap"] = loops
    return lap_us


def rss_kb(pid):
    try:
        for line in open(f"/proc/{pid}/status"):
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def run_looped(site, evs, loops, workdir, extra=()):
    """Runs the localizer on `loops` laps through a FIFO; returns RSS samples (wall s, lap, MB)."""
    fifo = pathlib.Path(workdir) / f"loop-{os.getpid()}.fifo"
    if fifo.exists():
        fifo.unlink()
    os.mkfifo(fifo)
    progress = {"lap": 0}
    writer = threading.Thread(target=write_loops, args=(evs, loops, fifo, progress), daemon=True)
    writer.start()
    p = subprocess.Popen([str(BIN / "localizer"), "--site", str(site), "--replay", str(fifo), "--out", "/dev/null"] + list(extra),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    samples, t0, last_print = [], time.monotonic(), -1
    while p.poll() is None:
        r = rss_kb(p.pid)
        if r is not None:
            samples.append((time.monotonic() - t0, progress["lap"], r / 1024.0))
            if progress["lap"] != last_print:
                last_print = progress["lap"]
                print(f"  lap {last_print + 1}/{loops}: RSS {r / 1024.0:.1f} MB", file=sys.stderr, flush=True)
        time.sleep(0.5)
    out, err = p.communicate()
    writer.join(timeout=5)
    fifo.unlink()
    if p.returncode != 0:
        raise RuntimeError(f"localizer exited {p.returncode}:\n{err}")
    return samples, err


def pose_messages(log):
    return [ev.data for ev in locbench.lcm.EventLog(str(log), "r") if ev.channel == "POSE"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loops", type=int, default=16, help="laps of the 232 s drive (default 16: 62 min)")
    a = ap.parse_args()
    if not (SITE / "map.tiles").exists():
        sys.exit(f"bench-localizer-memory: {SITE}/map.tiles is missing (make builds it)")
    OUT.mkdir(parents=True, exist_ok=True)
    print("bench-localizer-memory: simulating the 232 s lap (cached)", file=sys.stderr)
    drive = locbench.make_drive(OUT / "drive", 4, "aggressive", 232)
    evs = read_events(drive)
    lap_s = (evs[-1][0] - evs[0][0]) / 1e6 + 0.1
    with tempfile.TemporaryDirectory(dir=OUT) as tmp:
        whole = ["--map-radius", "1000000"]
        # 1. one lap to files, both maps: poses identical?
        res = {}
        for name, extra in (("paged", []), ("whole", whole)):
            out = pathlib.Path(tmp) / f"{name}.lcm"
            t = time.monotonic()
            p = locbench.run_localizer(drive, out, ["--site", SITE] + extra)
            if p.returncode != 0:
                raise RuntimeError(f"localizer ({name}) exited {p.returncode}:\n{p.stderr}")
            res[name] = {"wall_s": time.monotonic() - t, "poses": pose_messages(out),
                         "score": locbench.score_run(drive, out)}
        same = res["paged"]["poses"] == res["whole"]["poses"]
        npose = len(res["paged"]["poses"])
        # 2. RSS: one lap with the whole map, then LOOPS laps paged
        print("bench-localizer-memory: one lap, whole map", file=sys.stderr)
        whole_samples, _ = run_looped(SITE, evs, 1, tmp, whole)
        print(f"bench-localizer-memory: {a.loops} laps, paged map", file=sys.stderr)
        paged_samples, paged_err = run_looped(SITE, evs, a.loops, tmp)

    def lap_rss(samples, lap):
        v = [s[2] for s in samples if s[1] == lap]
        return (min(v), max(v)) if v else (float("nan"), float("nan"))

    whole_peak = max(s[2] for s in whole_samples)
    paged_peak = max(s[2] for s in paged_samples)
    after = [s[2] for s in paged_samples if s[1] >= 1]   # after the first lap (warm-up)
    lo, hi = (min(after), max(after)) if after else (float("nan"), float("nan"))
    spread = (hi - lo) / lo if after else float("nan")
    start, end = (after[0], after[-1]) if after else (float("nan"), float("nan"))
    wall_min = paged_samples[-1][0] / 60 if paged_samples else float("nan")
    print(f"\nbench-localizer-memory: default site, drive seed 4 aggressive, lap {lap_s:.1f} s; RSS = VmRSS sampled "
          f"every 0.5 s wall; {a.loops} laps = {a.loops * lap_s / 60:.1f} min of driving replayed")
    print("| map | laps | replayed min | wall min | RSS peak MB | after lap 1: start MB | end MB | min MB | max MB | "
          "max/min |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(f"| every tile held (whole map) | 1 | {lap_s / 60:.1f} | {whole_samples[-1][0] / 60:.1f} | {whole_peak:.1f} "
          f"| | | | | |")
    print(f"| paged (default) | {a.loops} | {a.loops * lap_s / 60:.1f} | {wall_min:.1f} | {paged_peak:.1f} | "
          f"{start:.1f} | {end:.1f} | {lo:.1f} | {hi:.1f} | {hi / lo:.3f} |")
    print("\nper lap (paged): " + ", ".join(f"{k + 1}: {lap_rss(paged_samples, k)[1]:.1f}" for k in range(a.loops)) + " MB (max)")
    sp, sw = res["paged"]["score"], res["whole"]["score"]
    print(f"\none lap to files: POSE messages {'byte-identical' if same else 'DIFFERENT'} with and without paging "
          f"({npose} POSE); paged median {sp.get('t_median', float('nan')):.3f} m p99 {sp.get('t_p99', float('nan')):.3f} m, "
          f"LOST after tracking {sp.get('lost_after_tracking')}; whole median {sw.get('t_median', float('nan')):.3f} m "
          f"p99 {sw.get('t_p99', float('nan')):.3f} m")
    met_mem = paged_peak <= 150
    met_flat = spread <= 0.05
    print(f"targets: RSS <= 150 MB: {'met' if met_mem else 'NOT MET'} ({paged_peak:.1f} MB); flat within 5% over "
          f"{a.loops * lap_s / 60:.0f} min: {'met' if met_flat else 'NOT MET'} ({100 * spread:.1f}%); poses identical: "
          f"{'met' if same else 'NOT MET'}")
    json.dump({"lap_s": lap_s, "loops": a.loops, "whole_peak_mb": whole_peak, "paged_peak_mb": paged_peak,
               "paged_after_lap1_min_mb": lo, "paged_after_lap1_max_mb": hi, "spread": spread,
               "paged_after_lap1_start_mb": start, "paged_end_mb": end, "paged_wall_min": wall_min,
               "poses_identical": same, "poses": npose, "paged_score": sp, "whole_score": sw,
               "paged_samples": paged_samples, "whole_samples": whole_samples,
               "paged_stderr_tail": paged_err[-2000:]},
              open(OUT / "results.json", "w"), indent=1)
    print(f"written {OUT / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
