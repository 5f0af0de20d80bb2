#!/usr/bin/env python3
"""bench-bus: the live bus under the car's load, for 10 minutes.

A publisher puts 10 Hz LiDAR sweeps (64 x 1024 range images of one closed lap of a
simulated drive, cycled and re-stamped to the wall clock), 200 Hz POSE_PREDICTED and 60 Hz AGENTS (12 agents) on a
private bus. A supervised stack listens: the session recorder (build/bin/recorder), the
localizer (LIDAR_SCAN), lab_vehicle (AGENTS) and log-summary (every channel). Measured:
- every message sent is in the recording (counted per channel, the files read strictly);
- every live module received every message of its channels (its STATUS input counts);
- resident memory of every process (the supervisor's 1 Hz figures per process group, and
  the supervisor's own) is flat: after one lap of the drive (the localizer pages the map's
  tiles around the car, so its memory follows the route until it has seen all of it),
  the largest and the last 30 s median within 5% of the first (a module holds one 332 KB
  sweep more or fewer at any instant, so one 1 Hz sample is no trend; the largest raw
  sample is printed beside it).
Baselines, measured in the same run on the same stream: lcm-logger (from the lcm wheel,
recording beside the recorder), and a subscriber with LCM's default 30-message queue
(what a module gets without pb_bus raising it to 1000).
Writes build/bench/bus.json and prints the table.

    modules/supervisor/bench/bench_bus.py [--duration S] [--port N]
"""
import argparse
import collections
import json
import os
import pathlib
import signal
import statistics
import struct
import subprocess
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "build" / "python"))
import lcm  # noqa: E402

import portobello  # noqa: E402

BIN = ROOT / "build" / "bin"
OUT = ROOT / "build" / "bench"
CHANNELS = {"LIDAR_SCAN": 10.0, "POSE_PREDICTED": 200.0, "AGENTS": 60.0}
# The localizer publishes POSE_PREDICTED too: module rows count the channels only the bench
# publishes; the recorder and the baseline tell the bench's POSE_PREDICTED by its bytes.
CONSUMERS = {"localizer": ["LIDAR_SCAN"], "lab_vehicle": ["AGENTS"], "log-summary": ["LIDAR_SCAN", "AGENTS"]}

STACK = """# bench-bus: written by modules/supervisor/bench/bench_bus.py
name: bench-bus
workdir: {root}
output_dir: {run}/output
defaults: {{heartbeat_s: 5, start_grace_s: 60, stop_timeout_s: 5, backoff_initial_s: 0.1, backoff_max_s: 5,
            stable_s: 10, max_failures: 3}}
groups:
  - name: recorder
    commands:
      - name: recorder
        run: [build/bin/recorder, --participant, BENCH, --session, bus, --dir, {run}/recordings, --split-mb, "1024"]
      - name: lcm-logger
        run: [tools/record.sh, --participant, BENCH, --session, lcmlogger, --dir, {run}/recordings, --split-mb, "1024"]
        ready: started
        heartbeat_s: 0
  - name: modules
    commands:
      - name: localizer
        run: [build/bin/localizer, --site, maps/default, --no-imu, --no-speed, --no-gnss, --initial-pose, "{init}"]
      - name: lab_vehicle
        run: [build/bin/lab_vehicle, --site, maps/default, --require-agents]
      - name: log-summary
        run: [build/bin/log-summary]
"""


def stamp(buf, utime):
    """Every portobello message: 8-byte fingerprint, then int64 utime (big-endian)."""
    return buf[:8] + struct.pack(">q", utime) + buf[16:]


def now_us():
    return time.time_ns() // 1000


def load_scans(run):
    """One closed lap of the default site's drive: from the middle of the car's rest at
    its first stop line to the middle of its rest there a lap later. Cycled, the scans
    run on without a jump (the car at rest at the same place), so the localizer tracks
    the whole time as on a real drive instead of being teleported back and searching."""
    d = run / "lap"
    if not (d / "drive.lcm").exists():
        subprocess.run([str(BIN / "simdrive"), "--seed", "3", "--duration", "290", "--out", str(d)], check=True)
    gts, scans = [], []
    for ev in lcm.EventLog(str(d / "drive.lcm"), "r"):
        if ev.channel == "GROUND_TRUTH":
            gts.append(portobello.pose_t.decode(ev.data))
        elif ev.channel == "LIDAR_SCAN":
            scans.append((struct.unpack(">q", ev.data[8:16])[0], ev.data))
    rests, first = [], None          # (start, end, x, y) of each rest after the start
    for a, b in zip(gts, gts[1:]):
        still = abs(b.position[0] - a.position[0]) + abs(b.position[1] - a.position[1]) < 1e-4
        if still and first is None:
            first = a
        elif not still and first is not None:
            if first.utime > gts[0].utime + 5e6:
                rests.append((first.utime, a.utime, first.position[0], first.position[1]))
            first = None
    again = [r for r in rests[1:] if abs(r[2] - rests[0][2]) + abs(r[3] - rests[0][3]) < 0.05] if rests else []
    if not again:
        raise SystemExit(f"bench-bus: {d}/drive.lcm holds no lap from a stop line back to it")
    t0, t1 = (rests[0][0] + rests[0][1]) // 2, (again[0][0] + again[0][1]) // 2
    lap = [buf for t, buf in scans if t0 <= t < t1]
    start = min(gts, key=lambda g: abs(g.utime - t0))
    return lap, start


def templates():
    p = portobello.pose_t()
    p.utime, p.position, p.orientation = 0, [1.0, 2.0, 0.0], [1.0, 0.0, 0.0, 0.0]
    p.velocity, p.angular_velocity, p.covariance = [5.0, 0, 0], [0, 0, 0], [0.0] * 36
    p.status, p.source, p.match_score = portobello.pose_t.STATUS_TRACKING, portobello.pose_t.SOURCE_PREDICTED, 0.0
    a = portobello.agents_t()
    a.utime, a.scenario = 0, "bench"
    for i in range(12):
        g = portobello.agent_t()
        g.id, g.kind, g.model, g.animation = f"ped_{i:02d}", "pedestrian", "ped_adult_m1", "walk"
        g.position, g.velocity, g.yaw_rad = [400.0 + i, 300.0, 0.0], [1.4, 0, 0], 0.0
        g.animation_phase, g.in_render_range, g.distance_m = 0.5, False, 300.0
        a.agents.append(g)
    a.nagents = len(a.agents)
    return p.encode(), a.encode()


class Listener:
    """STATUS, SUPERVISOR, and the baseline subscriber with LCM's default queue."""

    def __init__(self, url, pose_buf):
        self.pose_tail = pose_buf[16:]
        self.lc = lcm.LCM(url)
        self.lock = threading.Lock()
        self.status = {}                 # module -> last status_t
        self.rss = collections.defaultdict(list)   # name -> [(t, bytes)]
        self.sup = None
        self.baseline = collections.Counter()
        self.lc.subscribe("STATUS", self.on_status).set_queue_capacity(1000)
        self.lc.subscribe("SUPERVISOR", self.on_sup).set_queue_capacity(1000)
        self.base_lc = lcm.LCM(url)
        for ch in CHANNELS:
            self.base_lc.subscribe(ch, self.on_base)          # default queue: 30 messages
        self.stop = False
        self.threads = [threading.Thread(target=self.loop, args=(c,), daemon=True) for c in (self.lc, self.base_lc)]
        for t in self.threads:
            t.start()

    def on_status(self, ch, data):
        m = portobello.status_t.decode(data)
        with self.lock:
            self.status[m.module] = m

    def on_sup(self, ch, data):
        m = portobello.supervisor_t.decode(data)
        t = time.monotonic()
        with self.lock:
            self.sup = m
            for c in m.commands:
                if c.pid > 0 and c.rss_bytes > 0:
                    self.rss[c.name].append((t, c.rss_bytes))
            try:
                with open(f"/proc/{m.pid}/statm") as f:
                    self.rss["supervisor"].append((t, int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")))
            except OSError:
                pass

    def on_base(self, ch, data):
        if ch != "POSE_PREDICTED" or data[16:] == self.pose_tail:
            self.baseline[ch] += 1

    def loop(self, lc):
        while not self.stop:
            lc.handle_timeout(50)

    def close(self):
        self.stop = True
        for t in self.threads:
            t.join()


def publish(url, duration, scans, pose_buf, agents_buf, progress):
    """Paced on the monotonic clock: every message goes out at its own slot."""
    lc = lcm.LCM(url)
    sent = collections.Counter()
    period = {ch: 1.0 / hz for ch, hz in CHANNELS.items()}
    t0 = time.monotonic()
    nxt = {ch: t0 for ch in CHANNELS}
    last_print = t0
    while True:
        ch = min(nxt, key=nxt.get)
        t = nxt[ch]
        if t - t0 >= duration:
            break
        delay = t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        u = now_us()
        if ch == "LIDAR_SCAN":
            lc.publish(ch, stamp(scans[sent[ch] % len(scans)], u))
        elif ch == "POSE_PREDICTED":
            lc.publish(ch, stamp(pose_buf, u))
        else:
            lc.publish(ch, stamp(agents_buf, u))
        sent[ch] += 1
        nxt[ch] += period[ch]
        if progress and time.monotonic() - last_print >= 30:
            last_print = time.monotonic()
            print(f"  {last_print - t0:5.0f} / {duration:.0f} s: " +
                  ", ".join(f"{c} {n}" for c, n in sorted(sent.items())), flush=True)
    return sent, time.monotonic() - t0


def read_strict(path, pose_tail):
    data = path.read_bytes()
    i, counts = 0, collections.Counter()
    while i < len(data):
        sync, _, _, ch, ln = struct.unpack(">IqqII", data[i:i + 28])
        if sync != 0xEDA1DA01 or i + 28 + ch + ln > len(data):
            raise SystemExit(f"{path}: byte {i}: the recording does not end cleanly")
        name = data[i + 28:i + 28 + ch].decode()
        if name != "POSE_PREDICTED" or data[i + 28 + ch + 16:i + 28 + ch + ln] == pose_tail:
            counts[name] += 1
        i += 28 + ch + ln
    return counts


def flatness(samples, warmup_s, window_s=30):
    """Growth after the warm-up, judged on medians over window_s: a module that receives
    332 KB sweeps holds one more or one fewer at any instant (8% of a 4 MB process), so a
    single 1 Hz sample is no trend. The raw max is kept beside it."""
    if not samples:
        return None
    t_first = samples[0][0]
    after = [(t, v) for t, v in samples if t - t_first >= warmup_s]
    if len(after) < 2:
        return None
    med = [statistics.median(v for u, v in after if t - window_s / 2 <= u <= t + window_s / 2) for t, _ in after]
    ref, mx, raw = med[0], max(med), max(v for _, v in after)
    return {"ref_mb": ref / 1e6, "max_mb": mx / 1e6, "last_mb": med[-1] / 1e6, "raw_max_mb": raw / 1e6,
            "max_growth_pct": (mx - ref) / ref * 100, "last_growth_pct": (med[-1] - ref) / ref * 100,
            "raw_max_growth_pct": (raw - ref) / ref * 100, "window_s": window_s, "samples": len(after)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=600, help="seconds of load (default 600)")
    ap.add_argument("--port", type=int, default=7995, help="private multicast port (default 7995)")
    ap.add_argument("--warmup", type=float, default=None,
                    help="RSS is compared after this (default: one lap of the drive, about 270 s: the localizer "
                         "holds the map's tiles around the car, so its memory follows the route until it has "
                         "seen all of it once)")
    a = ap.parse_args()
    url = f"udpm://239.255.76.67:{a.port}?ttl=0&recv_buf_size=8388608"
    run = OUT / "bus"
    subprocess.run(["rm", "-rf", str(run / "recordings"), str(run / "output")], check=True)
    run.mkdir(parents=True, exist_ok=True)
    scans, gt = load_scans(run)
    if a.warmup is None:
        a.warmup = len(scans) / CHANNELS["LIDAR_SCAN"]
    init = ",".join(f"{v:.4f}" for v in list(gt.position) + [0.0, 0.0, 0.0]) if gt else "0,0,0,0,0,0"
    if gt:
        w, x, y, z = gt.orientation
        import math
        yaw = math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
        init = ",".join(f"{v:.4f}" for v in list(gt.position) + [0.0, 0.0, yaw])
    stack = run / "stack.yaml"
    stack.write_text(STACK.format(root=ROOT, run=run, init=init))
    pose_buf, agents_buf = templates()
    print(f"bench-bus: {a.duration:.0f} s of LIDAR_SCAN 10 Hz ({len(scans[0]) // 1000} KB), POSE_PREDICTED 200 Hz, "
          f"AGENTS 60 Hz on {url}", flush=True)

    lis = Listener(url, pose_buf)
    env = dict(os.environ, LCM_DEFAULT_URL=url)
    sup = subprocess.Popen([str(BIN / "supervisor"), "--config", str(stack)], env=env,
                           stdout=subprocess.DEVNULL, stderr=open(run / "supervisor.log", "w"))
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end:
            with lis.lock:
                ready = lis.sup and all(c.state == portobello.command_state_t.STATE_RUNNING for c in lis.sup.commands)
            if ready:
                break
            time.sleep(0.2)
        else:
            raise SystemExit("bench-bus: the stack did not come up in 120 s (see build/bench/bus/supervisor.log)")
        time.sleep(2)
        base0 = dict(status_counts(lis))
        sent, took = publish(url, a.duration, scans, pose_buf, agents_buf, True)
        time.sleep(3)        # the last messages are handled and a STATUS reports them
        final = status_counts(lis)
        with lis.lock:
            restarts = {c.name: c.restarts for c in lis.sup.commands}
    finally:
        sup.send_signal(signal.SIGTERM)
        sup.wait(timeout=60)
        lis.close()
    recs = sorted((run / "recordings").glob("BENCH_bus.lcm.*"))
    rec = collections.Counter()
    for f in recs:
        rec += read_strict(f, pose_buf[16:])
    base_rec = collections.Counter()
    for f in sorted((run / "recordings").glob("BENCH_lcmlogger.lcm.*")):
        base_rec += read_strict(f, pose_buf[16:])

    rows = []
    for ch in CHANNELS:
        rows.append({"what": f"recorder {ch}", "sent": sent[ch], "got": rec[ch]})
    for mod, chans in CONSUMERS.items():
        for ch in chans:
            got = final.get(mod, {}).get(ch, 0) - base0.get(mod, {}).get(ch, 0)
            rows.append({"what": f"{mod} {ch}", "sent": sent[ch], "got": got})
    for ch in CHANNELS:
        rows.append({"what": f"baseline: lcm-logger {ch}", "sent": sent[ch], "got": base_rec[ch]})
    for ch in CHANNELS:
        rows.append({"what": f"baseline: default 30-deep queue {ch}", "sent": sent[ch], "got": lis.baseline[ch]})
    mem = {name: flatness(s, a.warmup) for name, s in sorted(lis.rss.items())}

    print(f"\nbench-bus: {took:.0f} s of load; recording {sum(f.stat().st_size for f in recs) / 1e9:.2f} GB in {len(recs)} file(s)")
    print(f"{'receiver':<44} {'sent':>8} {'received':>9} {'lost':>6}")
    for r in rows:
        print(f"{r['what']:<44} {r['sent']:>8} {r['got']:>9} {r['sent'] - r['got']:>6}")
    print(f"\nresident memory, medians over 30 s (raw: the largest 1 Hz sample)")
    print(f"{'process (group)':<14} {'RSS at ' + str(int(a.warmup)) + ' s':>12} {'max MB':>8} {'last MB':>8} {'max growth':>11} {'raw max':>8} {'flat':>5}")
    flat_all = True
    for name, m in mem.items():
        if m is None or name == "lcm-logger":
            continue
        ok = m["max_growth_pct"] <= 5
        flat_all &= ok
        print(f"{name:<14} {m['ref_mb']:>10.1f} MB {m['max_mb']:>8.1f} {m['last_mb']:>8.1f} {m['max_growth_pct']:>+10.2f}% "
              f"{m['raw_max_growth_pct']:>+7.1f}% {'yes' if ok else 'NO':>5}")
    lost_ours = sum(r["sent"] - r["got"] for r in rows if not r["what"].startswith("baseline"))
    print(f"\nrestarts during the run: {restarts}")
    print(f"verdict: {'no message lost' if lost_ours == 0 else f'{lost_ours} messages lost'} by the recorder and the "
          f"modules; memory {'flat (within 5%)' if flat_all else 'NOT flat'}")
    OUT.mkdir(exist_ok=True)
    (OUT / "bus.json").write_text(json.dumps({
        "duration_s": took, "url": url, "rates_hz": CHANNELS, "scan_bytes": len(scans[0]), "rows": rows,
        "rss": mem, "warmup_s": a.warmup,
        "rss_series_mb": {n: [[round(t - v[0][0], 1), round(b / 1e6, 2)] for t, b in v[::5]] for n, v in lis.rss.items()},
        "restarts": restarts, "recording_files": [str(f) for f in recs],
        "lost": lost_ours, "memory_flat": flat_all}, indent=1))
    print(f"wrote {OUT / 'bus.json'}")
    return 0 if lost_ours == 0 and flat_all else 1


def status_counts(lis):
    with lis.lock:
        return {mod: {i.channel: i.count for i in st.inputs} for mod, st in lis.status.items()}


if __name__ == "__main__":
    sys.exit(main())
