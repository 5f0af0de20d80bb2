"""Study folders and session recordings: from LCM logs to one row per encounter.

A study folder holds `study.csv` (participant, order, platform, recording: one row per
recording, paths relative to the folder). An encounter is one synchronised pedestrian
of a scenario (a behaviour with `sync` in the scenario file) met at its stop line; the
scenario is named by the recording's SCENARIO_EVENTs and read from SITE/scenarios/.
"""
import csv
import io
import math
import pathlib
import struct
import sys

import numpy as np
import yaml

ORDERS = ("lab_first", "road_first")
PLATFORMS = ("lab", "road")
STATES = ("approaching", "at_kerb", "on_crosswalk", "cleared", "not_crossing")

SPEED_REST = 0.1        # m/s: the car is at rest (the director's standstill threshold)
KERB_ZONE_M = 1.5       # beyond either end of the crosswalk: "at the kerb"
CROSSWALK_MARGIN_M = 0.5  # along the road on either side of the stripes: still "on" it
NEAR_MISS_M = 1.0       # footprint to agent, without contact
STOP_REACH_M = 12.0     # the car's base origin rests within this of its stop line


class StudyError(Exception):
    """Bad input: the message names the file and line."""


# ---------------------------------------------------------------- the study folder
def csv_rows(path, columns):
    """(line, stripped values of columns) for every non-empty row of a CSV whose header
    has those columns (in any order, among others); a missing column, a row of the
    wrong length or an empty participant raise StudyError with FILE:LINE."""
    try:
        raw = pathlib.Path(path).read_bytes()
    except OSError as e:
        raise StudyError(f"{path}: {e.strerror}")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[:e.start].count(b"\n") + 1
        raise StudyError(f"{path}:{line}: not UTF-8 text (byte {e.start})")
    rows = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(rows, None)
        if header is None:
            raise StudyError(f"{path}:1: empty file (header {','.join(columns)} expected)")
        header = [h.strip() for h in header]
        for col in columns:
            if col not in header:
                raise StudyError(f"{path}:1: missing column '{col}' (header {','.join(columns)} expected)")
        ix = [header.index(c) for c in columns]
        for row in rows:
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise StudyError(f"{path}:{rows.line_num}: {len(row)} fields, the header has {len(header)}")
            values = [row[i].strip() for i in ix]
            if "participant" in columns and not values[columns.index("participant")]:
                raise StudyError(f"{path}:{rows.line_num}: empty participant")
            yield rows.line_num, values
    except csv.Error as e:
        raise StudyError(f"{path}:{rows.line_num}: {e}")


def read_study(study_dir):
    """study.csv -> (participants {id: order}, recordings [(participant, platform, path, line)])."""
    path = pathlib.Path(study_dir) / "study.csv"
    if not path.exists():
        raise StudyError(f"{path}: no such file (a study folder holds study.csv)")
    participants, recordings = {}, []
    for line, (p, order, plat, rec) in csv_rows(path, ("participant", "order", "platform", "recording")):
        if order not in ORDERS:
            raise StudyError(f"{path}:{line}: order '{order}': expected lab_first or road_first")
        if plat not in PLATFORMS:
            raise StudyError(f"{path}:{line}: platform '{plat}': expected lab or road")
        if participants.setdefault(p, order) != order:
            raise StudyError(f"{path}:{line}: participant {p} has order {order} here, "
                             f"{participants[p]} on an earlier line")
        if rec:
            recordings.append((p, plat, pathlib.Path(study_dir) / rec, line))
    return participants, recordings


# ---------------------------------------------------------------- strict log reading
LCM_SYNC = 0xEDA1DA01


def read_lcm_log(path):
    """Every event of an LCM log as (channel, data). Strict: a bad sync word or a
    truncated event raises StudyError naming the byte offset (lcm's own reader skips
    damaged bytes silently)."""
    raw = pathlib.Path(path).read_bytes()
    out, off = [], 0
    while off < len(raw):
        if off + 28 > len(raw):
            raise StudyError(f"{path}: byte {off}: truncated event header")
        sync, _num, _ts, clen, dlen = struct.unpack_from(">IqqII", raw, off)
        if sync != LCM_SYNC:
            raise StudyError(f"{path}: byte {off}: bad sync word 0x{sync:08x}")
        end = off + 28 + clen + dlen
        if clen > 256 or end > len(raw):
            raise StudyError(f"{path}: byte {off}: event runs past the end of the file")
        out.append((raw[off + 28:off + 28 + clen].decode("utf-8", "replace"), raw[off + 28 + clen:end]))
        off = end
    return out


# ---------------------------------------------------------------- site, scenarios, vehicle
class Site:
    def __init__(self, site_dir, vehicle_file):
        site_dir = pathlib.Path(site_dir)
        route = yaml.safe_load(open(site_dir / "route.yaml"))
        self.crosswalks = {c["id"]: c for c in route.get("crosswalks", [])}
        self.stop_lines = {s["id"]: s for s in route.get("stop_lines", [])}
        self.scenarios = {}     # scenario id -> [encounter dicts]
        for f in sorted((site_dir / "scenarios").glob("*.yaml")):
            sc = yaml.safe_load(open(f))
            agents = {a["id"]: a for a in sc.get("agents", [])}
            encs = []
            for b in sc.get("behaviours", []):
                if "sync" not in b:
                    continue
                sl = self.stop_lines[b["sync"]["stop_line"]]
                a = agents[b["agent"]]
                encs.append({"scenario": sc["scenario"], "agent": b["agent"], "stop_line": sl["id"],
                             "crosswalk": sl["crosswalk"], "agent_radius": a.get("radius", 0.3)})
            self.scenarios[sc["scenario"]] = encs
        veh = yaml.safe_load(open(vehicle_file))["dimensions"]
        self.car_length, self.car_width, self.rear_overhang = veh["length"], veh["width"], veh["rear_overhang"]


def _frame(c):
    """Unit vectors along the road and across it for a crosswalk or stop line."""
    yaw = math.radians(c["yaw_deg"])
    return np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])


def ped_zone(cw, xy):
    """Where a point lies relative to a crosswalk: 'on', 'kerb' or 'off'."""
    along_u, across_u = _frame(cw)
    d = np.asarray(xy[:2]) - np.asarray(cw["center"])
    along, across = abs(d @ along_u), abs(d @ across_u)
    if along > cw["width"] / 2 + CROSSWALK_MARGIN_M:
        return "off"
    if across <= cw["length"] / 2:
        return "on"
    if across <= cw["length"] / 2 + KERB_ZONE_M:
        return "kerb"
    return "off"


def box_distance(site, pose_xy, yaw, pt):
    """Distance from a point to the car's footprint (0 inside)."""
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = pt[0] - pose_xy[0], pt[1] - pose_xy[1]
    lx, ly = c * dx + s * dy, -s * dx + c * dy           # in base
    ex = max(-site.rear_overhang - lx, 0.0, lx - (site.car_length - site.rear_overhang))
    ey = max(abs(ly) - site.car_width / 2, 0.0)
    return math.hypot(ex, ey)


# ---------------------------------------------------------------- one recording
POSE_DTYPE = np.dtype([("fp", ">u8"), ("utime", ">i8"), ("position", ">f8", 3), ("orientation", ">f8", 4),
                       ("velocity", ">f8", 3), ("angular_velocity", ">f8", 3), ("covariance", ">f8", 36),
                       ("status", "i1"), ("source", "i1"), ("match_score", ">f4")])
AGENTS_STEP = 3     # AGENTS decoded: every 3rd (20 Hz of the director's 60 Hz), plus the one at each press


class Recording:
    """The channels of one recording that the analysis uses. Poses are parsed in one
    go with numpy (pose_t has a fixed size); AGENTS are kept raw and decoded on demand."""

    def __init__(self, path, pose_channel=None):
        import portobello
        self.path = path
        chans = {}
        for ch, data in read_lcm_log(path):
            chans.setdefault(ch, []).append(data)
        pc = pose_channel or ("POSE" if "POSE" in chans else "GROUND_TRUTH")
        if pc not in chans:
            raise StudyError(f"{path}: no POSE or GROUND_TRUTH channel")
        raw = chans[pc]
        if any(len(d) != POSE_DTYPE.itemsize for d in raw):
            raise StudyError(f"{path}: {pc}: a message of {next(len(d) for d in raw if len(d) != POSE_DTYPE.itemsize)} "
                             f"bytes is no pose_t ({POSE_DTYPE.itemsize})")
        poses = np.frombuffer(b"".join(raw), dtype=POSE_DTYPE)
        fp = struct.unpack(">Q", portobello.pose_t._get_packed_fingerprint())[0]
        if (poses["fp"] != fp).any():
            raise StudyError(f"{path}: {pc}: a message that is no pose_t (fingerprint)")
        poses = poses[(poses["status"] == portobello.pose_t.STATUS_TRACKING) |
                      (poses["status"] == portobello.pose_t.STATUS_DEGRADED)]
        if len(poses) == 0:
            raise StudyError(f"{path}: no tracking pose on {pc}")
        self.pose_t = poses["utime"].astype(np.int64)
        self.pose_xy = poses["position"][:, :2].astype(float)
        q = poses["orientation"].astype(float)
        self.pose_yaw = np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))
        self.speed = np.hypot(poses["velocity"][:, 0], poses["velocity"][:, 1]).astype(float)
        self.events = [portobello.scenario_event_t.decode(d) for d in chans.get("SCENARIO_EVENT", [])]
        self.presses = sorted(i.utime for i in (portobello.participant_input_t.decode(d)
                                                for d in chans.get("PARTICIPANT_INPUT", []))
                              if i.input == "proceed" and i.value != 0)
        self._agents_raw = chans.get("AGENTS", [])
        afp = portobello.agents_t._get_packed_fingerprint()
        if any(d[:8] != afp or len(d) < 16 for d in self._agents_raw):
            raise StudyError(f"{path}: AGENTS: a message that is no agents_t (fingerprint)")
        self.agents_t = np.array([struct.unpack_from(">q", d, 8)[0] for d in self._agents_raw], dtype=np.int64)
        self._agents_cache = {}
        self.t0 = int(self.pose_t[0])
        self.scenarios = sorted({e.scenario for e in self.events})

    def agent_positions(self, k):
        """{agent id: (x, y)} of the k-th AGENTS message."""
        if k not in self._agents_cache:
            import portobello
            a = portobello.agents_t.decode(self._agents_raw[k])
            self._agents_cache[k] = {g.id: (g.position[0], g.position[1]) for g in a.agents}
        return self._agents_cache[k]

    def agent_track(self, agent, t0, t1, extra=()):
        """(utimes, positions) of one agent between t0 and t1, at AGENTS_STEP, plus the
        messages at or just before the utimes in extra."""
        lo, hi = np.searchsorted(self.agents_t, [t0, t1])
        ks = set(range(int(lo), int(hi), AGENTS_STEP))
        for t in extra:
            k = int(np.searchsorted(self.agents_t, t, side="right")) - 1
            if k >= 0:
                ks.add(k)
        ks = sorted(k for k in ks if agent in self.agent_positions(k))
        return self.agents_t[ks] if ks else np.array([], dtype=np.int64), [self.agent_positions(k)[agent] for k in ks]


def _rest_intervals(rec, idx):
    """(start, end) pose indices of rest intervals among the pose indices idx (sorted)."""
    out, start = [], None
    for k, i in enumerate(idx):
        if start is None:
            start = i
        if k + 1 == len(idx) or idx[k + 1] != i + 1:
            out.append((start, i))
            start = None
    return out


def rests_at(rec, sl):
    """(first, last) pose index of every rest of the car at a stop line: speed under
    SPEED_REST, base origin at most STOP_REACH_M before the line and within 4 m of its lane."""
    along_u, across_u = _frame(sl)
    d = rec.pose_xy - np.asarray(sl["xy"])
    ahead = -(d @ along_u)                      # metres the base origin is before the line
    near = (ahead > 0) & (ahead < STOP_REACH_M) & (np.abs(d @ across_u) < 4.0) & (rec.speed < SPEED_REST)
    return _rest_intervals(rec, np.flatnonzero(near))


def encounter_rows(rec, site, participant, platform, order, rec_name):
    """One dict per encounter of the recording's scenarios, plus the collisions list."""
    rows, collisions = [], []
    encs = [e for s in rec.scenarios for e in site.scenarios.get(s, [])]
    found = []
    for e in encs:
        rests = rests_at(rec, site.stop_lines[e["stop_line"]])
        found.append((e, rests[0] if rests else None))
    found.sort(key=lambda f: f[1][0] if f[1] else 1 << 62)
    for e, rest in found:
        cw = site.crosswalks[e["crosswalk"]]
        row = {"participant": participant, "platform": platform, "order": order, "recording": rec_name,
               "scenario": e["scenario"], "stop_line": e["stop_line"], "agent": e["agent"]}
        if rest is None:
            row.update(decision="no_stop")
            rows.append(row)
            continue
        i0, i1 = rest
        t_stop, t_go = int(rec.pose_t[i0]), int(rec.pose_t[i1])
        row["stop_s"] = (t_stop - rec.t0) * 1e-6
        row["stopped_for_s"] = (t_go - t_stop) * 1e-6
        marks = [ev.utime for ev in rec.events if ev.kind == "mark" and ev.agent_id == e["agent"]
                 and ev.scenario == e["scenario"]]
        if marks:
            row["arrival_offset_s"] = (marks[0] - t_stop) * 1e-6   # + pedestrian after the car
        # the pedestrian's track from 10 s before the stop to 20 s after the departure
        press = next((p for p in rec.presses if t_stop <= p <= t_go + 500_000), None)
        track_t, track = rec.agent_track(e["agent"], t_stop - 10_000_000, t_go + 20_000_000,
                                         [press] if press else [])
        on = np.array([ped_zone(cw, p) == "on" for p in track], dtype=bool)
        t_on = t_clear = None
        if on.any():
            k_on = int(np.argmax(on))
            k_off = k_on + int(np.argmax(~on[k_on:])) if (~on[k_on:]).any() else None
            t_on = int(track_t[k_on])
            t_clear = int(track_t[k_off]) if k_off is not None else None
        if press is None:
            row["decision"] = "no_press"
        else:
            row["press_after_stop_s"] = (press - t_stop) * 1e-6
            if t_clear is not None:
                row["press_after_clear_s"] = (press - t_clear) * 1e-6
            if t_on is None:
                state = "not_crossing"
            elif t_clear is not None and press >= t_clear:
                state = "cleared"
            elif press >= t_on:
                state = "on_crosswalk"
            else:
                k = int(np.searchsorted(track_t, press, side="right")) - 1
                state = "at_kerb" if k >= 0 and ped_zone(cw, track[k]) == "kerb" else "approaching"
            row["decision"] = state
            row["cooperative"] = "n/a" if t_on is None else ("yes" if state == "cleared" else "no")
        # near miss: the closest the footprint came to the pedestrian around the encounter
        dmin = math.inf
        if len(track_t):
            ip = np.clip(np.searchsorted(rec.pose_t, track_t), 0, len(rec.pose_t) - 1)
            for k, i in enumerate(ip):
                dmin = min(dmin, box_distance(site, rec.pose_xy[i], rec.pose_yaw[i], track[k]) - e["agent_radius"])
        row["min_distance_m"] = max(dmin, 0.0) if math.isfinite(dmin) else None
        row["collisions"] = 0
        rows.append(row)
    # every collision event once: to the encounter of its agent, else the nearest stop in time
    for ev in (ev for ev in rec.events if ev.kind == "collision"):
        target = next((r for r in rows if r["agent"] == ev.agent_id and r["scenario"] == ev.scenario
                       and "stop_s" in r), None)
        if target is None:
            timed = [r for r in rows if "stop_s" in r and r["scenario"] == ev.scenario]
            t = (ev.utime - rec.t0) * 1e-6
            target = min(timed, key=lambda r: abs(r["stop_s"] - t)) if timed else None
        collisions.append({"participant": participant, "platform": platform, "order": order,
                           "recording": rec_name, "scenario": ev.scenario, "agent": ev.agent_id,
                           "t_s": (ev.utime - rec.t0) * 1e-6,
                           "stop_line": target["stop_line"] if target else ""})
        if target is not None:
            target["collisions"] += 1
    for r in rows:
        if "min_distance_m" in r:
            r["near_miss"] = "yes" if (r["collisions"] == 0 and r["min_distance_m"] is not None
                                        and r["min_distance_m"] < NEAR_MISS_M) else "no"
    return rows, collisions


ENCOUNTER_COLUMNS = ["participant", "platform", "order", "recording", "scenario", "stop_line", "agent",
                     "stop_s", "stopped_for_s", "decision", "press_after_stop_s", "press_after_clear_s",
                     "cooperative", "collisions", "min_distance_m", "near_miss", "arrival_offset_s"]


def analyse_study(study_dir, site, pose_channel=None, progress=True):
    """All encounters and collisions of a study folder, the recordings skipped (with
    reasons) and the number of recordings listed."""
    participants, recordings = read_study(study_dir)
    rows, collisions, skipped = [], [], []
    for n, (p, plat, path, line) in enumerate(recordings):
        if progress:
            print(f"\r  recording {n + 1}/{len(recordings)}", end="", file=sys.stderr, flush=True)
        name = str(path.relative_to(study_dir)) if path.is_relative_to(study_dir) else str(path)
        try:
            if not path.exists():
                raise StudyError(f"{path}: missing (study.csv line {line})")
            rec = Recording(path, pose_channel)
            if not rec.scenarios:
                raise StudyError(f"{path}: no SCENARIO_EVENT: no scenario ran")
            r, c = encounter_rows(rec, site, p, plat, participants[p], name)
        except StudyError as e:
            skipped.append({"recording": name, "participant": p, "platform": plat, "reason": str(e)})
            continue
        except Exception as e:     # an undecodable message: reported, the study goes on
            skipped.append({"recording": name, "participant": p, "platform": plat,
                            "reason": f"{path}: cannot decode: {type(e).__name__}: {e}"})
            continue
        rows += r
        collisions += c
    if progress and recordings:
        print(file=sys.stderr)
    return participants, rows, collisions, skipped, len(recordings)
