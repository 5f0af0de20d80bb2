"""study-synth: a synthetic twinned study whose decisions are known.

A participant model (cooperative, impatient, random) decides, at every crosswalk
encounter, in which state of the staged pedestrian it presses Proceed, and when. The
sessions are then made by the project's own programs:
  lab:  lab_vehicle --replay (the model's PARTICIPANT_INPUT presses; no director in the
        loop, so the twin departs at the press), then the director on its POSE;
  road: simdrive (the car rests at each stop until the press plus the safety driver's
        reaction), then the director on its GROUND_TRUTH.
Each recording is the merge (log-merge) of the vehicle, the presses and the director.

The model knows the pedestrian's plan, not the logs: a probe drive per platform and
scenario (the car waiting 25 s at every encounter) gives the time of the director's
`mark` event relative to the car's rest; the pedestrian's phases after the mark follow
from its path in the scenario file (leg lengths, speeds, waits) and the crosswalk's
extent across the road. Presses are placed at least MARGIN_S inside a phase.

Writes STUDY_DIR/study.csv, the recordings, truth.csv (the model's decision per
encounter) and questionnaire.csv (synthetic ratings, a few answers missing).
"""
import argparse
import concurrent.futures as cf
import csv
import math
import os
import pathlib
import random
import struct
import subprocess
import sys
import tempfile

import numpy as np
import yaml

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parents[1]
BIN = ROOT / "build" / "bin"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "build" / "python"))

from sessions import Recording, Site, _frame, rests_at  # noqa: E402

UTIME0 = 1714572000000000      # simdrive's and lab_vehicle's fixed epoch
MODELS = ("cooperative", "impatient", "random")
MARGIN_S = 0.6                 # a press lies at least this far inside the chosen phase
MIN_DELAY_S = 0.5              # earliest press after the car comes to rest
PROBE_HOLD_S = 25.0            # probe drives wait this long at every encounter
REACTION_S = 1.0               # road: the safety driver moves off this long after the press
OTHER_STOP_DELAY_S = 2.0       # stops without an encounter
MEASURES = ("presence", "realism", "safety", "trust", "workload")


# ---------------------------------------------------------------- small log writing
def write_log(path, events):
    """events: (utime, channel, bytes) in time order -> an LCM log."""
    with open(path, "wb") as f:
        for n, (t, ch, data) in enumerate(events):
            c = ch.encode()
            f.write(struct.pack(">IqqII", 0xEDA1DA01, n, t, len(c), len(data)) + c + data)


def press_msg(t):
    import portobello
    m = portobello.participant_input_t()
    m.utime, m.input, m.device, m.value = t, "proceed", "study_synth", 1
    return m.encode()


def run(args):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} exited {p.returncode}: {p.stderr[-1500:]}")


# ---------------------------------------------------------------- one session
def make_drive(platform, scenario_file, site_dir, delays, duration, work, out):
    """Drives with the given press delays (s after rest, per stop met, in order) and
    runs the director: writes the merged recording `out`; returns the rest times the
    presses were placed after (s since UTIME0)."""
    work = pathlib.Path(work)
    presses = work / "presses.lcm"
    if platform == "lab":
        # the twin's rest times do not depend on when it left the previous stop, so they
        # follow from its reference lap (rest_k measured with a 2 s press) and the delays
        rests = lab_reference_rests(site_dir)
        shift, times = 0.0, []
        used = []
        for k, d in enumerate(delays):
            used.append(rests[k] + shift)
            times.append(rests[k] + shift + d)
            shift += d - OTHER_STOP_DELAY_S
        ev = []
        n_ticks = int(duration / 0.05) + 1
        pt = [UTIME0 + int(round(t * 1e6)) for t in times]
        for i in range(n_ticks):
            ev.append((UTIME0 + i * 50_000, "SYNTH_CLOCK", b""))
        ev += [(t, "PARTICIPANT_INPUT", press_msg(t)) for t in pt]
        ev.sort(key=lambda e: (e[0], e[1] != "SYNTH_CLOCK"))
        write_log(work / "lab_in.lcm", ev)
        write_log(presses, [(t, "PARTICIPANT_INPUT", press_msg(t)) for t in pt])
        run([BIN / "lab_vehicle", "--site", site_dir, "--replay", work / "lab_in.lcm", "--out", work / "vehicle.lcm"])
        pose = "POSE"
    else:
        args = [BIN / "simdrive", "--site", site_dir, "--seed", 7, "--duration", f"{duration:.2f}", "--no-lidar",
                "--quiet", "--out", work / "road"]
        for d in delays:
            args += ["--dwell", f"{d + REACTION_S:.3f}"]
        run(args)
        (work / "road" / "drive.lcm").rename(work / "vehicle.lcm")
        used = rest_starts(work / "vehicle.lcm", "GROUND_TRUTH", site_dir)[:len(delays)]
        if len(used) < len(delays):
            raise RuntimeError(f"simdrive made {len(used)} stops in {duration:.0f} s, {len(delays)} wanted")
        pt = [UTIME0 + int(round((used[k] + d) * 1e6)) for k, d in enumerate(delays)]
        write_log(presses, [(t, "PARTICIPANT_INPUT", press_msg(t)) for t in pt])
        pose = "GROUND_TRUTH"
    run([BIN / "log-merge", "--quiet", "--out", work / "in.lcm", work / "vehicle.lcm", presses])
    run([BIN / "director", "--site", site_dir, "--scenario", scenario_file, "--pose-channel", pose,
         "--replay", work / "in.lcm", "--out", work / "director.lcm"])
    run([BIN / "log-merge", "--quiet", "--out", out, work / "in.lcm", work / "director.lcm"])
    return used


_LAB_RESTS = {}


def lab_reference_rests(site_dir):
    """Rest start of every stop (s since the start) on the twin's lap with 2 s presses."""
    if site_dir not in _LAB_RESTS:
        import portobello
        with tempfile.TemporaryDirectory() as tmp:
            log = pathlib.Path(tmp) / "lab.lcm"
            run([BIN / "lab_vehicle", "--site", site_dir, "--out", log, "--auto-proceed", OTHER_STOP_DELAY_S])
            import lcm
            rests = []
            for ev in lcm.EventLog(str(log), "r"):
                if ev.channel == "LAB_EVENT":
                    e = portobello.scenario_event_t.decode(ev.data)
                    if e.event_id == "awaiting_proceed":
                        rests.append((e.utime - UTIME0) * 1e-6)
        _LAB_RESTS[site_dir] = rests
    return _LAB_RESTS[site_dir]


def rest_starts(log, channel, site_dir):
    """Rest start (s since UTIME0) at every stop line met, in order, from a pose channel."""
    site = yaml.safe_load(open(pathlib.Path(site_dir) / "route.yaml"))
    rec = Recording(log, channel)
    out = []
    for sl in site["stop_lines"]:
        for i0, _ in rests_at(rec, sl):
            out.append((rec.pose_t[i0] - UTIME0) * 1e-6)
    return sorted(out)


# ---------------------------------------------------------------- the pedestrian's plan
def phases(site, scenario_file, encounter, mark_rel):
    """[(state, start, end)] in s relative to the car's rest, from the scenario's path."""
    sc = yaml.safe_load(open(scenario_file))
    beh = next(b for b in sc["behaviours"] if b.get("agent") == encounter["agent"] and "sync" in b)
    cw = site.crosswalks[encounter["crosswalk"]]
    _, across_u = _frame(cw)
    half = cw["length"] / 2
    path = beh["path"]
    mark = beh["sync"]["mark"]
    t = mark_rel + path[mark].get("wait_s", 0.0)
    pos = np.asarray(path[mark]["to"], float)
    on_start = on_end = None
    for wp in path[mark + 1:]:
        to = np.asarray(wp["to"], float)
        dur = np.linalg.norm(to - pos) / wp.get("speed", 1.4)
        a0 = (pos - cw["center"]) @ across_u
        a1 = (to - cw["center"]) @ across_u
        if a0 != a1:      # the part of the leg within the crosswalk's extent across the road
            u0, u1 = sorted(((-half - a0) / (a1 - a0), (half - a0) / (a1 - a0)))
            u0, u1 = max(u0, 0.0), min(u1, 1.0)
            if u0 < u1:
                if on_start is None:
                    on_start = t + u0 * dur
                on_end = t + u1 * dur
        t += dur + wp.get("wait_s", 0.0)
        pos = to
    if on_start is None:
        return [("not_crossing", -math.inf, math.inf)]
    return [("approaching", -math.inf, mark_rel), ("at_kerb", mark_rel, on_start),
            ("on_crosswalk", on_start, on_end), ("cleared", on_end, on_end + 6.0)]


def decide(model, plan, rng):
    """(state, delay after rest) the model presses in."""
    feasible = []
    for state, a, b in plan:
        a, b = max(a, MIN_DELAY_S) + MARGIN_S, min(b, PROBE_HOLD_S - 2.0) - MARGIN_S
        if b > a:
            feasible.append((state, a, b))
    if model == "cooperative":
        pick = next((f for f in feasible if f[0] in ("cleared", "not_crossing")), feasible[-1])
        return pick[0], rng.uniform(pick[1], min(pick[2], pick[1] + 2.0))
    if model == "impatient":
        pick = feasible[0]
        return pick[0], rng.uniform(pick[1], min(pick[2], pick[1] + 0.4))
    pick = rng.choice(feasible)
    return pick[0], rng.uniform(pick[1], pick[2])


# ---------------------------------------------------------------- the study
def probe(platform, scenario_file, site_dir, site, encs, tmp):
    """Mark time relative to the rest, per encounter, and the stop index of each."""
    stops = ordered_stops(site_dir)
    idx = {e["stop_line"]: stops.index(e["stop_line"]) for e in encs}
    nstop = max(idx.values()) + 1
    delays = [PROBE_HOLD_S if k in idx.values() else OTHER_STOP_DELAY_S for k in range(nstop)]
    work = pathlib.Path(tmp) / f"probe_{platform}_{pathlib.Path(scenario_file).stem}"
    work.mkdir()
    rests = make_drive(platform, scenario_file, site_dir, delays, drive_duration(site_dir, delays), work,
                       work / "rec.lcm")
    rec = Recording(work / "rec.lcm", "POSE" if platform == "lab" else "GROUND_TRUTH")
    out = {}
    for e in encs:
        k = idx[e["stop_line"]]
        marks = [ev.utime for ev in rec.events if ev.kind == "mark" and ev.agent_id == e["agent"]]
        rest = rests[k]
        out[e["stop_line"]] = ((marks[0] - UTIME0) * 1e-6 - rest, k, rest)
    return out, rests


def drive_duration(site_dir, delays):
    """Long enough to see the last encounter through: the twin's reference rest at the
    last stop, moved by the delays, plus the last delay and 25 s."""
    ref = lab_reference_rests(site_dir)
    n = len(delays)
    return ref[n - 1] + sum(d - OTHER_STOP_DELAY_S for d in delays[:-1]) + delays[-1] + 25.0


def ordered_stops(site_dir):
    route = yaml.safe_load(open(pathlib.Path(site_dir) / "route.yaml"))
    return [s["id"] for s in route["stop_lines"]]


def session_job(job):
    (p, platform, scen_file, site_dir, delays, duration, out) = job
    with tempfile.TemporaryDirectory() as tmp:
        make_drive(platform, scen_file, site_dir, delays, duration, tmp, out)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="study-synth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="study folder to write (created)")
    ap.add_argument("--participants", type=int, default=32, help="participants (default 32)")
    ap.add_argument("--scenarios", default="all",
                    help="comma-separated scenario file names of the site (default: all)")
    ap.add_argument("--site", default=str(ROOT / "maps" / "default"))
    ap.add_argument("--seed", type=int, default=1, help="seed of the models' choices and the ratings")
    ap.add_argument("--jobs", type=int, default=2, help="sessions made in parallel (default 2)")
    a = ap.parse_args(argv)
    if a.participants < 2:
        ap.error("--participants must be at least 2")
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    site = Site(a.site, ROOT / "vehicles" / "prius2017.yaml")
    files = sorted((pathlib.Path(a.site) / "scenarios").glob("*.yaml"))
    if a.scenarios != "all":
        want = a.scenarios.split(",")
        files = [f for f in files if f.stem in want]
        if len(files) != len(want):
            ap.error(f"--scenarios: unknown scenario among {want}")
    rng = random.Random(a.seed)
    stops = ordered_stops(a.site)
    jobs, truth, study = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        probes = {}
        for platform in ("lab", "road"):
            for f in files:
                sid = yaml.safe_load(open(f))["scenario"]
                encs = site.scenarios[sid]
                print(f"study-synth: probe {platform} {f.stem}", file=sys.stderr)
                probes[(platform, f)] = (sid, encs, probe(platform, f, a.site, site, encs, tmp)[0])
        for i in range(a.participants):
            p = f"p{i + 1:02d}"
            model = MODELS[i % len(MODELS)]
            order = "lab_first" if i % 2 == 0 else "road_first"
            (out / p).mkdir(exist_ok=True)
            for platform in ("lab", "road"):
                for f in files:
                    sid, encs, pr = probes[(platform, f)]
                    nstop = max(pr[e["stop_line"]][1] for e in encs) + 1
                    delays = [OTHER_STOP_DELAY_S] * nstop
                    for e in encs:
                        mark_rel, k, _ = pr[e["stop_line"]]
                        state, delay = decide(model, phases(site, f, e, mark_rel), rng)
                        delays[k] = delay
                        truth.append({"participant": p, "platform": platform, "scenario": sid,
                                      "stop_line": e["stop_line"], "agent": e["agent"], "model": model,
                                      "decision": state, "press_after_stop_s": f"{delay:.3f}"})
                    name = f"{p}/{platform}_{f.stem}.lcm"
                    study.append({"participant": p, "order": order, "platform": platform, "recording": name})
                    jobs.append((p, platform, f, a.site, delays, drive_duration(a.site, delays), out / name))
        print(f"study-synth: {len(jobs)} sessions", file=sys.stderr)
        done = 0
        with cf.ThreadPoolExecutor(max(1, a.jobs)) as ex:
            for _ in ex.map(session_job, jobs):
                done += 1
                print(f"\r  session {done}/{len(jobs)}", end="", file=sys.stderr, flush=True)
        print(file=sys.stderr)
    with open(out / "study.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, ["participant", "order", "platform", "recording"])
        w.writeheader()
        w.writerows(study)
    with open(out / "truth.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, list(truth[0]))
        w.writeheader()
        w.writerows(truth)
    write_questionnaire(out / "questionnaire.csv", a.participants, rng)
    print(f"study-synth: {a.participants} participants, {len(jobs)} recordings, {len(truth)} encounters -> {out}",
          file=sys.stderr)
    return 0


def write_questionnaire(path, n, rng):
    """Ratings 1-5: road rated higher on realism and presence, the rest alike; about 3 %
    of the answers left empty."""
    effect = {"presence": 0.8, "realism": 1.2, "safety": 0.0, "trust": 0.2, "workload": -0.1}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["participant", "platform", "measure", "value"])
        for i in range(n):
            base = {m: rng.gauss(3.0, 0.7) for m in MEASURES}
            for platform in ("lab", "road"):
                for m in MEASURES:
                    v = base[m] + (effect[m] if platform == "road" else 0.0) + rng.gauss(0, 0.6)
                    v = min(5, max(1, int(round(v))))
                    w.writerow([f"p{i + 1:02d}", platform, m, "" if rng.random() < 0.03 else v])


if __name__ == "__main__":
    sys.exit(main())
