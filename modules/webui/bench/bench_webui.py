#!/usr/bin/env python3
"""make bench-webui: the webui bridge against foxglove-sdk's WebSocket server (baseline), on
the same LCM feed, in the same run.

1. bus -> browser: POSE_PREDICTED at 200 Hz and AGENTS (12 agents) at 60 Hz; headless
   Chromium on /operator?probe records, for every message, Date.now() - utime (the feeder
   stamps utime with the wall clock as it publishes). Target p99 <= 30 ms.
2. Proceed press -> PARTICIPANT_INPUT on the bus: real clicks on /participant; the page's
   pointerdown time to the LCM receive time. Target p99 <= 50 ms.
3. Slow client: a client that reads one message every 0.2 s, subscribed to everything,
   for --soak-s (600 s = 10 minutes) against both relays at once, while the feed runs;
   each relay's RSS sampled every 10 s, and the age of what the slow client reads.
   Target: the bridge's memory flat (last minute vs second minute).
Writes build/bench/webui.json and prints a table."""
import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import threading
import time

ROOT = pathlib.Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "build" / "python"))

from webui_util import Bridge, Feeder, Listener, WsClient, chrome, wait_for  # noqa: E402

LCM = "udpm://239.255.76.67:{}?ttl=0&recv_buf_size=8388608"


def pct(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else float("nan")


def rss_kb(pid):
    text = pathlib.Path(f"/proc/{pid}/status").read_text()
    for line in text.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"/proc/{pid}/status has no VmRSS (process gone?):\n{text[:200]}")


def latency_windows(urls, seconds, windows):
    """Alternating windows (A B A B ...) so the shared machine's load hits both relays alike."""
    lat = {k: [] for k in urls}
    per_window = {}
    for w in range(windows):
        for label, url in urls.items():
            d = chrome((1024, 600))
            try:
                d.get(url)
                wait_for(lambda: d.execute_script("return window.__lat.length") > 100, 60, f"{label}: messages in the page")
                time.sleep(2)
                d.execute_script("window.__lat.length = 0")
                time.sleep(seconds / windows)
                got = d.execute_script("return window.__lat.slice()")
                lat[label] += got
                per_window.setdefault(label, []).append(round(pct([x[1] for x in got], 99), 1))
            finally:
                d.quit()
    return {k: {**summarise(v, seconds), "p99_ms_per_window": per_window[k]} for k, v in lat.items()}


def summarise(lat, seconds):
    out = {}
    for ch, rate in (("POSE_PREDICTED", 200), ("AGENTS", 60)):
        v = [x[1] for x in lat if x[0] == ch]
        out[ch] = {"n": len(v), "expected": rate * seconds, "p50_ms": pct(v, 50), "p99_ms": pct(v, 99), "max_ms": max(v) if v else None}
    return out


def proceed(url, lcm_url, presses):
    import portobello
    got = Listener(lcm_url, "PARTICIPANT_INPUT", portobello.participant_input_t)
    d = chrome((400, 760))
    try:
        d.get(url + "/participant")
        wait_for(lambda: "connected" in d.find_element("id", "info").text, 30, "participant connected")
        d.execute_script("window.__press = []; document.getElementById('proceed').addEventListener('pointerdown', () => window.__press.push(Date.now()), true)")
        button = d.find_element("id", "proceed")
        for _ in range(presses):
            button.click()
            time.sleep(0.7)            # beyond the page's 0.6 s debounce: every click is a press
        time.sleep(1)
        press = d.execute_script("return window.__press")
    finally:
        d.quit()
        got.stop()
    rx = [r / 1000 for r, _ in got.got]
    lat = [r - p for p, r in zip(press, rx)]
    return {"presses": len(press), "inputs": len(rx), "p50_ms": pct(lat, 50), "p99_ms": pct(lat, 99), "max_ms": max(lat) if lat else None}


class SlowClient(threading.Thread):
    def __init__(self, url, period_s, subprotocol="foxglove.websocket.v1"):
        super().__init__(daemon=True)
        self.c = WsClient(url, subprotocol)
        self.period = period_s
        self.ages = []            # (t, age of the message read, s)
        self.stop_flag = False

    def run(self):
        import struct
        subscribed = set()
        next_id = 1
        while not self.stop_flag:
            try:
                m = self.c.ws.recv(timeout=1)
            except TimeoutError:
                continue
            except Exception:
                break
            if isinstance(m, str):
                op = json.loads(m)
                if op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
                        if ch["id"] not in subscribed:
                            subscribed.add(ch["id"])
                            subs.append({"id": next_id, "channelId": ch["id"]})
                            next_id += 1
                    if subs:
                        self.c.send_json({"op": "subscribe", "subscriptions": subs})
                continue
            if m[0] == 1:
                ts = struct.unpack_from("<Q", m, 5)[0]
                self.ages.append((time.time(), time.time_ns() / 1e9 - ts / 1e9))
                time.sleep(self.period)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60, help="latency measured per relay (s), split into windows")
    ap.add_argument("--windows", type=int, default=4, help="alternating windows per relay")
    ap.add_argument("--presses", type=int, default=60)
    ap.add_argument("--soak-s", type=float, default=600, help="slow-client soak (s), 10 minutes by default")
    ap.add_argument("--out", default=str(ROOT / "build" / "bench" / "webui.json"))
    args = ap.parse_args()
    import tempfile
    from webui_util import site_copy
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-webui-"))
    site = site_copy(tmp)
    lcm_url = LCM.format(8030)
    bridge = Bridge(site, 18010, lcm_url)
    sdk = subprocess.Popen([sys.executable, str(ROOT / "modules/webui/bench/sdk_relay.py"), lcm_url, "18011"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    feed = Feeder(lcm_url, pose_hz=200, agents_hz=60)
    feed.start()
    res = {"feed": {"POSE_PREDICTED_hz": 200, "AGENTS_hz": 60, "agents": 12}}
    try:
        time.sleep(3)
        print(f"bus -> browser: webui bridge and foxglove-sdk server (baseline), {args.windows} alternating windows each ...", flush=True)
        lat = latency_windows({"webui": bridge.url + "/operator?probe", "sdk": bridge.url + "/operator?probe&ws=127.0.0.1:18011"},
                              args.seconds, args.windows)
        res["latency_webui"], res["latency_sdk"] = lat["webui"], lat["sdk"]
        print("proceed press -> PARTICIPANT_INPUT ...", flush=True)
        res["proceed"] = proceed(bridge.url, lcm_url, args.presses)
        print(f"slow client soak, {args.soak_s:.0f} s, both relays ...", flush=True)
        slow = {"webui": SlowClient(bridge.ws + "/operator", 0.2), "sdk": SlowClient("ws://127.0.0.1:18011/", 0.2, "foxglove.sdk.v1")}
        for s in slow.values():
            s.start()
        pids = {"webui": bridge.proc.pid, "sdk": sdk.pid}
        samples = {k: [] for k in pids}
        t0 = time.time()
        while time.time() - t0 < args.soak_s:
            for k, pid in pids.items():
                samples[k].append((round(time.time() - t0, 1), rss_kb(pid)))
            print(f"  {time.time() - t0:5.0f} s  RSS webui {samples['webui'][-1][1] / 1024:6.1f} MB  sdk {samples['sdk'][-1][1] / 1024:6.1f} MB",
                  flush=True)
            time.sleep(10)
        for k, s in slow.items():
            s.stop_flag = True
        soak = {}
        for k in pids:
            rs = samples[k]
            first = [r for t, r in rs if 60 <= t < 120] or [r for _, r in rs[:6]]
            last = [r for t, r in rs if t >= args.soak_s - 60] or [r for _, r in rs[-6:]]
            ages = [a for t, a in slow[k].ages if t - t0 >= args.soak_s - 60] or [a for _, a in slow[k].ages]
            soak[k] = {"rss_mb_second_minute": statistics.mean(first) / 1024, "rss_mb_last_minute": statistics.mean(last) / 1024,
                       "rss_mb_max": max(r for _, r in rs) / 1024, "growth_pct": 100 * (statistics.mean(last) / statistics.mean(first) - 1),
                       "slow_client_reads": len(slow[k].ages), "slow_client_age_p50_s": pct(ages, 50),
                       "slow_client_age_max_s": max(ages) if ages else None, "rss_samples_kb": rs}
        res["soak_s"] = args.soak_s
        res["soak"] = soak
    finally:
        feed.stop()
        bridge.stop()
        sdk.terminate()
        sdk.wait(10)
    res["sent"] = feed.sent
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    # table
    print()
    print(f"{'bus -> browser (ms)':34s} {'webui p50':>9s} {'p99':>7s} {'max':>7s} {'n/sent':>12s} | {'sdk p50':>8s} {'p99':>7s} {'max':>7s} {'n/sent':>12s}")
    for ch in ("POSE_PREDICTED", "AGENTS"):
        a, b = res["latency_webui"][ch], res["latency_sdk"][ch]
        print(f"{ch + ' (target p99 <= 30)':34s} {a['p50_ms']:9.1f} {a['p99_ms']:7.1f} {a['max_ms']:7.1f} {a['n']:>6d}/{a['expected']:<5.0f} | "
              f"{b['p50_ms']:8.1f} {b['p99_ms']:7.1f} {b['max_ms']:7.1f} {b['n']:>6d}/{b['expected']:<5.0f}")
    print(f"{'p99 per window (ms, A B A B order)':34s} webui {res['latency_webui']['p99_ms_per_window']}  sdk {res['latency_sdk']['p99_ms_per_window']}")
    p = res["proceed"]
    print(f"{'proceed press -> bus (target p99 <= 50)':34s} {p['p50_ms']:9.1f} {p['p99_ms']:7.1f} {p['max_ms']:7.1f} {p['inputs']:>6d}/{p['presses']:<5d}")
    print(f"\nslow client ({args.soak_s:.0f} s; reads one message per 0.2 s)   RSS 2nd min -> last min (MB)   growth   age of what it reads p50 / max (s)")
    for k in ("webui", "sdk"):
        s = res["soak"][k]
        print(f"  {k:8s} {s['rss_mb_second_minute']:30.1f} -> {s['rss_mb_last_minute']:6.1f}   {s['growth_pct']:+6.1f} %   "
              f"{s['slow_client_age_p50_s']:8.3f} / {s['slow_client_age_max_s']:.3f}")
    print(f"\nwritten {out}")


if __name__ == "__main__":
    main()
