#!/usr/bin/env python3
"""log-fault: writes a copy of a drive log with one fault injected, for localizer tests
and benchmarks. Times (--at, --for) are seconds after the first event of the log.

  lidar-gap     drop every LIDAR_SCAN whose sweep starts in [at, at+for)
  jump          add an INITIAL_POSE at `at`: the GROUND_TRUTH pose of that moment moved
                --metres along the car's heading (forward, so it stays on the road, where
                the map's ground fits everywhere and scores stay high): the localizer is
                told a wrong pose while every sensor is healthy
  imu-gap       drop every IMU sample in [at, at+for)
  drop-channel  drop every event of --channel (e.g. GNSS_FIX, IMU)
  nan-points    replace --count sweeps after `at` by point-form sweeps whose points
                include NaN and inf coordinates (every 10th point) plus the real points
  empty-scans   replace --count sweeps after `at` by sweeps without points
  duplicate     repeat every IMU, LIDAR_SCAN and GNSS_FIX event in [at, at+for)
  reorder       swap each pair of successive IMU events, and each pair of LIDAR_SCAN
                events, in [at, at+for) (out-of-order delivery)
  garbage       replace --count LIDAR_SCAN payloads after `at` by bytes that do not decode
  gnss-jump     move every GNSS_FIX in [at, at+for) --metres to the east (multipath or
                spoofing: the localizer must not follow it)
  cut           keep only the events in [at, at+for) (a start in the middle of a drive,
                the car moving); --keep CH,CH,... keeps only those channels
  gnss-clock    add --seconds to every GNSS_FIX utime (a receiver whose clock is off the
                host's; the event times stay)
  head-clock    add --seconds to every HEAD_POSE utime (a headset whose clock is off the
                car's; the event times stay)
  time-step     from `at` on, subtract --seconds from every message utime and event time
                (the sensors' clock stepped back, e.g. an NTP or GNSS time sync)
  kidnap        drop every event in [at, at+for) and move the later ones back by `for`
                (message utimes and event times): the car's data jumps ahead along its
                drive while every sensor stays healthy and no clock jumps, so the pose the
                localizer holds is suddenly wrong (a kidnapped car; it stands for a pose
                gone wrong while tracking, which only the map can tell)
The log stays ordered by event timestamp except for `reorder` and `time-step`. Prints
what it did.
"""
import argparse
import math
import struct
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "python"))

import lcm  # noqa: E402
from portobello import lidar_scan_t, pose_t  # noqa: E402


def read_events(path):
    log = lcm.EventLog(str(path), "r")
    return [(ev.timestamp, ev.channel, ev.data) for ev in log]


def shift_utime(data, delta):
    """Every portobello message starts with its 8-byte fingerprint and int64 utime."""
    u = struct.unpack(">q", data[8:16])[0]
    return data[:8] + struct.pack(">q", u + delta) + data[16:]


def msg_utime(data):
    return int.from_bytes(data[8:16], "big", signed=True)


def edit_fixes(events, pick, change):
    """The events with each GNSS_FIX that pick(event) selects decoded, changed in place
    by change(fix) and encoded again; returns (events, how many fixes were changed)."""
    from portobello import gnss_fix_t
    out, n = [], 0
    for e in events:
        if e[1] == "GNSS_FIX" and pick(e):
            f = gnss_fix_t.decode(e[2])
            change(f)
            out.append((e[0], e[1], f.encode()))
            n += 1
        else:
            out.append(e)
    return out, n


def ground_truth_at(events, t):
    best = None
    for ts, ch, data in events:
        if ch == "GROUND_TRUTH":
            p = pose_t.decode(data)
            if p.utime >= t:
                return p
            best = p
    return best


def point_sweep(scan, with_nan, seed_pts):
    """A point-form sweep; with_nan adds NaN/inf points among the real ones."""
    s = lidar_scan_t()
    s.utime, s.sensor, s.seq = scan.utime, scan.sensor, scan.seq
    s.rows = s.cols = s.npixels = s.nsignal = 0
    s.range_mm, s.reflectivity, s.signal, s.near_ir, s.col_offset_us = [], [], [], [], []
    s.beam_altitude_rad, s.beam_azimuth_rad = [], []
    s.beam_origin_m = 0.0
    s.lidar_from_beam = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    xs, ys, zs, offs = [], [], [], []
    if with_nan:
        bad = [float("nan"), float("inf"), float("-inf")]
        for i, (x, y, z, o) in enumerate(seed_pts):
            if i % 10 == 0:
                xs.append(bad[i % 3]); ys.append(y); zs.append(z); offs.append(o)
            xs.append(x); ys.append(y); zs.append(z); offs.append(o)
    s.npoints = len(xs)
    s.x, s.y, s.z = xs, ys, zs
    s.intensity = [0.0] * s.npoints
    s.point_offset_us = offs
    s.ring = [255] * s.npoints
    return s


def range_image_points(log_path, scan_index):
    """The sweep's points (lidar frame), computed by common/pb_scan through
    build/bin/ouster-points, so the sensor model is implemented once."""
    out = subprocess.run([str(ROOT / "build" / "bin" / "ouster-points"), "--in", str(log_path),
                          "--scan", str(scan_index)], capture_output=True, text=True, check=True).stdout
    pts = []
    for line in out.splitlines()[1:]:
        f = line.split(",")
        pts.append((float(f[4]), float(f[5]), float(f[6]), int(f[8])))
    return pts


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("fault", choices=["lidar-gap", "jump", "imu-gap", "drop-channel", "nan-points", "empty-scans",
                                      "duplicate", "reorder", "garbage", "gnss-jump", "cut", "gnss-clock", "head-clock",
                                      "time-step", "kidnap"])
    ap.add_argument("--in", dest="inp", required=True, help="input log")
    ap.add_argument("--out", required=True, help="output log")
    ap.add_argument("--at", type=float, default=10.0, help="seconds after the log's first event (default 10)")
    ap.add_argument("--for", dest="dur", type=float, default=3.0, help="duration, seconds (default 3)")
    ap.add_argument("--metres", type=float, default=20.0, help="jump length (default 20)")
    ap.add_argument("--count", type=int, default=3, help="sweeps for nan-points / empty-scans / garbage")
    ap.add_argument("--channel", default="GNSS_FIX", help="channel for drop-channel")
    ap.add_argument("--keep", default="", help="cut: channels to keep, comma-separated (default all)")
    ap.add_argument("--seconds", type=float, default=2.0, help="gnss-clock / head-clock / time-step: seconds (default 2)")
    a = ap.parse_args()

    ev = read_events(a.inp)
    if not ev:
        sys.exit(f"log-fault: {a.inp}: no events")
    t0 = ev[0][0]
    t_at = t0 + int(a.at * 1e6)
    t_end = t_at + int(a.dur * 1e6)
    out = []
    note = ""
    if a.fault in ("lidar-gap", "imu-gap"):
        ch = "LIDAR_SCAN" if a.fault == "lidar-gap" else "IMU"
        dropped = [e for e in ev if e[1] == ch and t_at <= msg_utime(e[2]) < t_end]
        out = [e for e in ev if not (e[1] == ch and t_at <= msg_utime(e[2]) < t_end)]
        note = f"dropped {len(dropped)} {ch} events with utime in [{t_at}, {t_end})"
    elif a.fault == "drop-channel":
        out = [e for e in ev if e[1] != a.channel]
        note = f"dropped {len(ev) - len(out)} {a.channel} events"
    elif a.fault == "jump":
        gt = ground_truth_at(ev, t_at)
        if gt is None:
            sys.exit("log-fault: jump needs GROUND_TRUTH in the log")
        w, x, y, z = gt.orientation
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        p = pose_t()
        p.utime = gt.utime
        p.position = [gt.position[0] + a.metres * math.cos(yaw), gt.position[1] + a.metres * math.sin(yaw), gt.position[2]]
        p.orientation = list(gt.orientation)
        p.velocity = [0.0, 0.0, 0.0]
        p.angular_velocity = [0.0, 0.0, 0.0]
        p.covariance = [0.0] * 36
        p.status = pose_t.STATUS_TRACKING
        p.source = pose_t.SOURCE_OPERATOR
        p.match_score = float("nan")
        data = p.encode()
        inserted = False
        for e in ev:
            if not inserted and e[0] >= t_at:
                out.append((t_at, "INITIAL_POSE", data))
                inserted = True
            out.append(e)
        note = (f"INITIAL_POSE at {gt.utime}: ({p.position[0]:.2f}, {p.position[1]:.2f}), "
                f"{a.metres:.0f} m ahead of the true ({gt.position[0]:.2f}, {gt.position[1]:.2f})")
    elif a.fault in ("nan-points", "empty-scans", "garbage"):
        n = 0
        k = -1      # index of the sweep among the log's LIDAR_SCAN events
        for e in ev:
            k += e[1] == "LIDAR_SCAN"
            if e[1] == "LIDAR_SCAN" and msg_utime(e[2]) >= t_at and n < a.count:
                n += 1
                if a.fault == "garbage":
                    out.append((e[0], e[1], b"\x00" * 16 + bytes(range(256)) * 4))
                    continue
                s = lidar_scan_t.decode(e[2])
                if a.fault == "nan-points":
                    pts = range_image_points(a.inp, k) if s.npixels else list(zip(s.x, s.y, s.z, s.point_offset_us))
                    s2 = point_sweep(s, True, pts)
                else:
                    s2 = point_sweep(s, False, [])
                out.append((e[0], e[1], s2.encode()))
            else:
                out.append(e)
        note = f"{a.fault}: {n} sweeps from {t_at}"
    elif a.fault == "gnss-jump":
        def east(f):
            f.lon_deg += a.metres / (111320.0 * math.cos(math.radians(f.lat_deg)))
        out, n = edit_fixes(ev, lambda e: t_at <= msg_utime(e[2]) < t_end, east)
        note = f"moved {n} GNSS fixes {a.metres:.0f} m east"
    elif a.fault == "cut":
        keep = set(c for c in a.keep.split(",") if c)
        out = [e for e in ev if t_at <= e[0] < t_end and (not keep or e[1] in keep)]
        note = f"kept {len(out)} events in [{t_at}, {t_end})" + (f" of {', '.join(sorted(keep))}" if keep else "")
    elif a.fault == "gnss-clock":
        def later(f):
            f.utime += int(round(a.seconds * 1e6))
        out, n = edit_fixes(ev, lambda e: True, later)
        note = f"{n} GNSS_FIX utimes moved by {a.seconds:+.3f} s"
    elif a.fault == "head-clock":
        shift = int(round(a.seconds * 1e6))
        out = [(e[0], e[1], shift_utime(e[2], shift)) if e[1] == "HEAD_POSE" else e for e in ev]
        n = sum(e[1] == "HEAD_POSE" for e in ev)
        note = f"{n} HEAD_POSE utimes moved by {a.seconds:+.3f} s"
    elif a.fault == "time-step":
        shift = int(round(a.seconds * 1e6))
        n = 0
        for e in ev:
            if e[0] < t_at:
                out.append(e)
                continue
            out.append((e[0] - shift, e[1], shift_utime(e[2], -shift)))
            n += 1
        note = f"{n} events from {t_at} on stepped back {a.seconds:.3f} s"
    elif a.fault == "kidnap":
        shift = t_end - t_at
        out = [e if e[0] < t_at else (e[0] - shift, e[1], shift_utime(e[2], -shift)) for e in ev if not t_at <= e[0] < t_end]
        note = f"dropped {len(ev) - len(out)} events in [{t_at}, {t_end}), the later ones moved back {a.dur:.3f} s"
    elif a.fault == "duplicate":
        n = 0
        for e in ev:
            out.append(e)
            if e[1] in ("IMU", "LIDAR_SCAN", "GNSS_FIX") and t_at <= e[0] < t_end:
                out.append(e)
                n += 1
        note = f"repeated {n} events"
    elif a.fault == "reorder":
        pending = {}
        n = 0
        for e in ev:
            if e[1] in ("IMU", "LIDAR_SCAN") and t_at <= e[0] < t_end:
                if e[1] in pending:
                    first = pending.pop(e[1])
                    out.append((first[0], e[1], e[2]))      # the later message first
                    out.append((e[0], e[1], first[2]))
                    n += 1
                else:
                    pending[e[1]] = e
                continue
            out.append(e)
        out.extend(pending.values())
        note = f"swapped {n} pairs"
    log = lcm.EventLog(a.out, "w", overwrite=True)
    for ts, ch, data in out:
        log.write_event(ts, ch, data)
    log.close()
    print(f"log-fault {a.fault}: {note}; {len(out)} events written to {a.out}")


if __name__ == "__main__":
    main()
