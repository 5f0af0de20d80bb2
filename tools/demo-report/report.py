#!/usr/bin/env python3
"""demo-report: the crosswalk study on both platforms, as text and as one HTML page.

    tools/demo-report/report.py --site maps/default --lab LAB.lcm [...] --road ROAD.lcm [...] --out DIR

LAB logs: the lab twin's drive and the director run on it (POSE, GROUND_TRUTH, AGENTS,
SCENARIO_EVENT). ROAD logs: the recording of the supervised live replay (the played
drive with GROUND_TRUTH, the live modules' POSE, AGENTS, SCENARIO_EVENT, SUPERVISOR),
e.g. every file of recordings/P00_S1.lcm.*. Writes DIR/report.txt and DIR/report.html
(one self-contained page: tables and inline SVG) and prints their paths.

The report is a list of sections (SECTIONS below): each is a function taking the loaded
study and returning (title, text, html). A new section (study figures, links to
the web pages) is one function appended to SECTIONS.
"""
import argparse
import bisect
import html
import math
import pathlib
import struct
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "build" / "python"))

import yaml  # noqa: E402

import portobello  # noqa: E402

TRACKING = portobello.pose_t.STATUS_TRACKING
STATE_NAMES = ["STOPPED", "WAITING", "STARTING", "RUNNING", "BACKOFF", "STOPPING", "EXITED", "FAILED"]


# ------------------------------------------------------------------ reading logs

def read_events(path):
    """(channel, timestamp, data) of every event; a torn last event ends the file (with a
    warning naming its byte offset), as the project's replay does."""
    data = pathlib.Path(path).read_bytes()
    i = 0
    while i < len(data):
        if len(data) - i < 28:
            print(f"{path}: byte {i}: warning: the last event is torn; read up to byte {i}", file=sys.stderr)
            return
        sync, _, ts, ch, ln = struct.unpack(">IqqII", data[i:i + 28])
        if sync != 0xEDA1DA01:
            raise SystemExit(f"{path}: byte {i}: bad sync word 0x{sync:08x}: corrupt log")
        if i + 28 + ch + ln > len(data):
            print(f"{path}: byte {i}: warning: the last event is torn; read up to byte {i}", file=sys.stderr)
            return
        yield data[i + 28:i + 28 + ch].decode("ascii"), ts, data[i + 28 + ch:i + 28 + ch + ln]
        i += 28 + ch + ln


OCCLUSION_RANGE_M = 45.0   # the module's default --range and the scenarios' render distance


def occlusion_counts(m, a):
    """(visible, hidden, unknown) samples of one agent within OCCLUSION_RANGE_M of the eye; beyond
    it every sample is unknown by definition, which says nothing about occlusion."""
    n = [0, 0, 0]
    vx, vy, vz = m.viewer
    if not all(math.isfinite(v) for v in (vx, vy, vz)):
        return tuple(n)    # no usable pose: the module said unknown for all, counted as none in range
    for x, y, z, s in zip(a.sample_x, a.sample_y, a.sample_z, a.state):
        if math.dist((x, y, z), (vx, vy, vz)) <= OCCLUSION_RANGE_M and 0 <= s <= 2:
            n[s] += 1
    return tuple(n)


class Platform:
    """What one platform's logs hold, decoded."""

    def __init__(self, name, paths):
        self.name = name
        self.paths = [str(p) for p in paths]
        self.pose, self.truth, self.events, self.agents, self.supervisor = [], [], [], {}, None
        self.occlusion = []   # (utime, eye_source, {agent id: (visible, hidden, unknown) samples})
        for path in paths:
            for ch, _, d in read_events(path):
                if ch == "POSE":
                    p = portobello.pose_t.decode(d)
                    self.pose.append((p.utime, p.position[0], p.position[1], p.status))
                elif ch == "GROUND_TRUTH":
                    p = portobello.pose_t.decode(d)
                    self.truth.append((p.utime, p.position[0], p.position[1]))
                elif ch == "SCENARIO_EVENT":
                    self.events.append(portobello.scenario_event_t.decode(d))
                elif ch == "AGENTS":
                    m = portobello.agents_t.decode(d)
                    for a in m.agents:
                        track = self.agents.setdefault(a.id, [])
                        # keep one point per 0.2 s: the path, not every message
                        if not track or m.utime - track[-1][0] >= 200000:
                            track.append((m.utime, a.position[0], a.position[1]))
                elif ch == "SUPERVISOR":
                    self.supervisor = portobello.supervisor_t.decode(d)
                elif ch == "OCCLUSION":
                    m = portobello.occlusion_t.decode(d)
                    self.occlusion.append((m.utime, m.eye_source, {a.agent_id: occlusion_counts(m, a) for a in m.agents}))
        self.pose.sort()
        self.truth.sort()
        self.events.sort(key=lambda e: e.utime)
        starts = [t[0] for t in self.truth[:1]] + [p[0] for p in self.pose[:1]]
        self.t0 = min(starts) if starts else (self.events[0].utime if self.events else 0)

    def rel(self, utime):
        return (utime - self.t0) * 1e-6


class Study:
    def __init__(self, site, lab, road):
        self.site = pathlib.Path(site)
        self.route = yaml.safe_load((self.site / "route.yaml").read_text())
        self.lab, self.road = lab, road

    def pairs(self):
        """Lab and road SCENARIO_EVENTs side by side, in order, matched by (kind, id, agent)."""
        lab, road = self.lab.events, self.road.events
        return [(lab[i] if i < len(lab) else None, road[i] if i < len(road) else None)
                for i in range(max(len(lab), len(road)))]


def key(e):
    return (e.kind, e.event_id, e.agent_id) if e is not None else None


# ------------------------------------------------------------------ sections

def section_events(s):
    rows, text = [], []
    pairs = s.pairs()
    same = all(key(a) == key(b) for a, b in pairs)
    w = 44
    text.append(f"{'lab (lab twin)':<{w}} | road (supervised live replay)")
    for i, (a, b) in enumerate(pairs):
        def cell(e, p):
            return f"{p.rel(e.utime):7.2f} {e.kind:<8} {e.event_id} {e.agent_id}".rstrip()[:w] if e else ""
        text.append(f"{cell(a, s.lab):<{w}} | {cell(b, s.road)}")
        ok = key(a) == key(b)
        tds = []
        for e, p in ((a, s.lab), (b, s.road)):
            if e is None:
                tds.append('<td></td><td></td><td></td><td></td>')
            else:
                tds.append(f'<td class="t">{p.rel(e.utime):.2f}</td><td>{html.escape(e.kind)}</td>'
                           f'<td class="id">{html.escape(e.event_id)}</td><td>{html.escape(e.agent_id)}</td>')
        rows.append(f'<tr class="{"ok" if ok else "bad"}"><td>{i + 1}</td>{tds[0]}{tds[1]}'
                    f'<td>{"same" if ok else "DIFFERS"}</td></tr>')
    verdict = (f"{len(s.lab.events)} lab events, {len(s.road.events)} road events: sequences "
               f"{'IDENTICAL' if same else 'DIFFER'}")
    text.append(verdict)
    table = ('<table id="events"><thead><tr><th>#</th><th>lab s</th><th>kind</th><th>event</th><th>agent</th>'
             '<th>road s</th><th>kind</th><th>event</th><th>agent</th><th></th></tr></thead><tbody>'
             + "".join(rows) + "</tbody></table>")
    return ("SCENARIO_EVENT on both platforms", "\n".join(text),
            f'<p class="{"ok" if same else "bad"}" id="events-verdict">{html.escape(verdict)}</p>'
            '<p>Seconds since each drive started. Lab: the twin drives the route, the participant presses '
            '"proceed" 2 s after each stop. Road: the simulated drive played by lcm-logplayer in real time '
            'through the supervised live stack (can, localizer, director).</p>' + table)


def crosswalk_of(event_id, ids):
    head = event_id.split("_")[0]
    return head if head in ids else None


def section_timing(s):
    ids = [c["id"] for c in s.route.get("crosswalks", [])]
    per = {}
    for a, b in s.pairs():
        if a is None or b is None or key(a) != key(b):
            continue
        cw = crosswalk_of(a.event_id, ids)
        if cw:
            per.setdefault(cw, []).append((a, (b.utime - s.road.t0) * 1e-6 - (a.utime - s.lab.t0) * 1e-6))
    text = [f"{'crosswalk':<10} {'events':>6} {'first event':<22} {'offset s':>9} {'mean s':>8} {'max |s|':>8}"]
    rows = []
    for cw in ids:
        if cw not in per:
            continue
        offs = [o for _, o in per[cw]]
        first, o0 = per[cw][0]
        mean = sum(offs) / len(offs)
        mx = max(abs(o) for o in offs)
        text.append(f"{cw:<10} {len(offs):>6} {first.event_id:<22} {o0:>+9.2f} {mean:>+8.2f} {mx:>8.2f}")
        rows.append(f'<tr><td>{cw}</td><td>{len(offs)}</td><td class="id">{html.escape(first.event_id)}</td>'
                    f'<td class="t">{o0:+.2f}</td><td>{mean:+.2f}</td><td>{mx:.2f}</td></tr>')
    text.append("offset = road time - lab time of the same event (s since each drive's start)")
    return ("Timing offset per crosswalk", "\n".join(text),
            '<table id="timing"><thead><tr><th>crosswalk</th><th>matched events</th><th>first event</th>'
            '<th>offset s</th><th>mean offset s</th><th>max |offset| s</th></tr></thead><tbody>' + "".join(rows)
            + "</tbody></table><p>offset = road time &minus; lab time of the same event, seconds since each "
              "drive's start.</p>")


class Svg:
    """A top-down plot in map metres: x right, y up."""

    def __init__(self, xmin, xmax, ymin, ymax, width=1100):
        self.x0, self.y1 = xmin, ymax
        self.k = width / (xmax - xmin)
        self.w, self.h = width, (ymax - ymin) * self.k
        self.items = []

    def p(self, x, y):
        return f"{(x - self.x0) * self.k:.1f},{(self.y1 - y) * self.k:.1f}"

    def line(self, pts, cls):
        if len(pts) >= 2:
            self.items.append(f'<polyline class="{cls}" points="{" ".join(self.p(x, y) for x, y in pts)}"/>')

    def poly(self, pts, cls):
        self.items.append(f'<polygon class="{cls}" points="{" ".join(self.p(x, y) for x, y in pts)}"/>')

    def mark(self, x, y, cls, label=None, shape="circle"):
        cx, cy = self.p(x, y).split(",")
        if shape == "circle":
            self.items.append(f'<circle class="{cls}" cx="{cx}" cy="{cy}" r="5"><title>{html.escape(label or "")}</title></circle>')
        else:
            cxf, cyf = float(cx), float(cy)
            self.items.append(f'<polygon class="{cls}" points="{cxf:.1f},{cyf - 6:.1f} {cxf - 5.5:.1f},{cyf + 4:.1f} '
                              f'{cxf + 5.5:.1f},{cyf + 4:.1f}"><title>{html.escape(label or "")}</title></polygon>')
        if label:
            self.items.append(f'<text x="{float(cx) + 7:.1f}" y="{float(cy) - 7:.1f}" class="lbl">{html.escape(label)}</text>')

    def render(self, ident):
        return (f'<svg id="{ident}" xmlns="http://www.w3.org/2000/svg" width="{self.w:.0f}" height="{self.h:.0f}" '
                f'viewBox="0 0 {self.w:.0f} {self.h:.0f}"><rect width="100%" height="100%" fill="#fbfbf8"/>'
                + "".join(self.items) + "</svg>")


def rect(cx, cy, yaw_deg, length, width):
    """Corners of a length x width rectangle (length along yaw)."""
    c, s_ = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    out = []
    for u, v in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        du, dv = u * length / 2, v * width / 2
        out.append((cx + du * c - dv * s_, cy + du * s_ + dv * c))
    return out


def section_plot(s):
    lab_xy = [(x, y) for _, x, y, _ in s.lab.pose]
    road_xy = [(x, y) for _, x, y, st in s.road.pose if st == TRACKING]
    truth_xy = [(x, y) for _, x, y in s.road.truth]
    driven = lab_xy + road_xy + truth_xy
    if not driven:
        return ("Top-down view", "no poses in the logs", "<p>no poses in the logs</p>")
    m = 15
    xmin, xmax = min(x for x, _ in driven) - m, max(x for x, _ in driven) + m
    ymin, ymax = min(y for _, y in driven) - m, max(y for _, y in driven) + m
    svg = Svg(xmin, xmax, ymin, ymax)
    pts = [tuple(p) for p in s.route["points"]]
    svg.line(pts + ([pts[0]] if s.route.get("closed") else []), "route")
    lane = s.route.get("lane_width", 3.5)
    for cw in s.route.get("crosswalks", []):
        # the crosswalk's length runs across the road: along yaw + 90 degrees
        svg.poly(rect(cw["center"][0], cw["center"][1], cw["yaw_deg"] + 90, cw["length"], cw["width"]), "cw")
    for sl in s.route.get("stop_lines", []):
        c = rect(sl["xy"][0], sl["xy"][1], sl["yaw_deg"] + 90, lane, 0.01)
        svg.line([c[0], c[1]], "stop")
    for track in s.road.agents.values():
        svg.line([(x, y) for _, x, y in track], "agent")
    svg.line(truth_xy, "truth")
    svg.line(lab_xy, "lab")
    svg.line(road_xy, "road")
    n = 0
    for plat, cls, shape in ((s.lab, "lab-trig", "circle"), (s.road, "road-trig", "tri")):
        for e in plat.events:
            if e.kind == "trigger":
                svg.mark(e.vehicle.position[0], e.vehicle.position[1], cls,
                         e.event_id if plat is s.road else None, shape)
                n += 1
    legend = ('<p class="legend"><span class="k route"></span>route centreline <span class="k stop"></span>stop lines '
              '<span class="k cw"></span>crosswalks <span class="k lab"></span>lab twin <span class="k road"></span>road car '
              '(localizer POSE, tracking) <span class="k truth"></span>ground truth <span class="k agent"></span>agents '
              '(road) &#9679; lab trigger &#9650; road trigger</p>')
    return ("Top-down view", f"plot: {len(lab_xy)} lab poses, {len(road_xy)} road poses, {len(s.road.agents)} agents, "
            f"{n} triggers (see report.html)", legend + svg.render("topdown"))


def interp(track, t):
    ts = [p[0] for p in track]
    i = bisect.bisect_left(ts, t)
    if i == 0 or i >= len(track):
        return None
    (t0, x0, y0), (t1, x1, y1) = track[i - 1], track[i]
    a = (t - t0) / (t1 - t0) if t1 > t0 else 0
    return x0 + a * (x1 - x0), y0 + a * (y1 - y0)


def percentile(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(math.ceil(q * len(v))) - 1)] if v else float("nan")


def section_localization(s):
    err = []
    for t, x, y, st in s.road.pose:
        if st != TRACKING:
            continue
        g = interp(s.road.truth, t)
        if g:
            err.append((s.road.rel(t), math.hypot(x - g[0], y - g[1])))
    if not err:
        return ("Localization error along the route", "no tracking POSE with ground truth", "<p>none</p>")
    e = [v for _, v in err]
    summary = (f"{len(err)} tracking POSE: horizontal error median {percentile(e, 0.5) * 100:.1f} cm, "
               f"p95 {percentile(e, 0.95) * 100:.1f} cm, max {max(e) * 100:.1f} cm")
    w, h, pad = 1100, 260, 40
    tmax = max(t for t, _ in err) or 1
    emax = max(max(e) * 100, 1)
    pts = " ".join(f"{pad + t / tmax * (w - 2 * pad):.1f},{h - pad - v * 100 / emax * (h - 2 * pad):.1f}" for t, v in err)
    ticks = "".join(f'<text x="4" y="{h - pad - f * (h - 2 * pad) + 4:.1f}" class="lbl">{f * emax:.1f} cm</text>'
                    for f in (0, 0.5, 1))
    xt = "".join(f'<text x="{pad + f * (w - 2 * pad):.1f}" y="{h - 10}" class="lbl">{f * tmax:.0f} s</text>'
                 for f in (0, 0.25, 0.5, 0.75, 1))
    chart = (f'<svg id="locerr" xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}"><rect width="100%" height="100%" '
             f'fill="#fbfbf8"/><line x1="{pad}" y1="{h - pad}" x2="{w - pad}" y2="{h - pad}" stroke="#888"/>'
             f'<polyline class="err" points="{pts}"/>{ticks}{xt}</svg>')
    return ("Localization error along the route", summary,
            f'<p id="loc-summary">{html.escape(summary)}</p><p>Road car: the localizer\'s POSE (status tracking) '
            'against the simulated drive\'s GROUND_TRUTH at the same time, seconds since the drive started.</p>' + chart)


def section_supervisor(s):
    sup = s.road.supervisor
    if sup is None:
        return ("Supervised stack", "no SUPERVISOR message in the road logs", "<p>no SUPERVISOR message recorded</p>")
    text = [f"stack {sup.stack}: last state recorded"]
    rows = []
    for c in sup.commands:
        ex = "-" if c.last_exit == portobello.command_state_t.EXIT_NONE else str(c.last_exit)
        st = STATE_NAMES[c.state] if 0 <= c.state < len(STATE_NAMES) else "UNKNOWN"
        text.append(f"  {c.name:<12} {st:<9} restarts {c.restarts:<3} last exit {ex:<5} cpu {c.cpu_percent:5.1f}% "
                    f"rss {c.rss_bytes / 1e6:7.1f} MB")
        rows.append(f"<tr><td>{html.escape(c.name)}</td><td>{html.escape(c.group)}</td><td>{st}</td><td>{c.restarts}</td>"
                    f"<td>{ex}</td><td>{c.cpu_percent:.1f}</td><td>{c.rss_bytes / 1e6:.1f}</td>"
                    f"<td>{html.escape(c.detail)}</td></tr>")
    return ("Supervised stack", "\n".join(text),
            '<table id="supervisor"><thead><tr><th>command</th><th>group</th><th>state</th><th>restarts</th>'
            '<th>last exit</th><th>CPU %</th><th>RSS MB</th><th>detail</th></tr></thead><tbody>' + "".join(rows)
            + "</tbody></table>")


def section_occlusion(s):
    occ = s.road.occlusion
    if not occ:
        return ("Occlusion", "no OCCLUSION message in the road logs", "<p>no OCCLUSION message recorded</p>")
    eyes = {0: "HEAD_POSE", 1: "seat", 2: "LiDAR"}
    used = sorted({eyes.get(e, "?") for _, e, _ in occ})
    per = {}
    for _, _, agents in occ:
        for aid, counts in agents.items():
            per.setdefault(aid, [0, 0, 0, 0])
            for k in range(3):
                per[aid][k] += counts[k]
            per[aid][3] += sum(counts) > 0      # sweeps with the agent in range
    tot = [sum(v[k] for v in per.values()) for k in range(3)]
    n = sum(tot) or 1
    summary = (f"{len(occ)} OCCLUSION sweeps, eye from {', '.join(used)}; samples within "
               f"{OCCLUSION_RANGE_M:.0f} m of the eye: "
               f"visible {tot[0] / n * 100:.1f}%, hidden by real objects {tot[1] / n * 100:.1f}%, "
               f"unknown {tot[2] / n * 100:.1f}%")
    text, rows = [summary], []
    for aid in sorted(per):
        v, h, u, sweeps = per[aid]
        m = (v + h + u) or 1
        text.append(f"  {aid:<14} {sweeps:5d} sweeps in range  visible {v / m * 100:5.1f}%  hidden {h / m * 100:5.1f}%  "
                    f"unknown {u / m * 100:5.1f}%")
        rows.append(f"<tr><td class=id>{html.escape(aid)}</td><td>{sweeps}</td><td>{v / m * 100:.1f}</td>"
                    f"<td>{h / m * 100:.1f}</td><td>{u / m * 100:.1f}</td></tr>")
    return ("Occlusion", "\n".join(text),
            f'<p id="occ-summary">{html.escape(summary)}</p><p>Per agent, over the sweeps it was within '
            f'{OCCLUSION_RANGE_M:.0f} m of the eye, the share of its body samples that the occlusion module found '
            'visible, hidden behind something the LiDAR sees, or unknown (space the LiDAR has not observed).</p><table id="occlusion"><thead><tr><th>agent</th>'
            '<th>sweeps in range</th><th>visible %</th><th>hidden %</th><th>unknown %</th></tr></thead><tbody>'
            + "".join(rows) + "</tbody></table>")


# Append a function here to add a section (it receives the Study, returns (title, text, html)).
SECTIONS = [section_events, section_timing, section_plot, section_localization, section_occlusion, section_supervisor]

CSS = """
body{font-family:sans-serif;margin:24px;color:#222;max-width:1160px}
table{border-collapse:collapse;font-size:13px;margin:8px 0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}
tr.bad td{background:#fdd} .ok{color:#060} .bad{color:#a00}
td.id{font-family:monospace}
.route{fill:none;stroke:#bbb;stroke-width:9;stroke-linejoin:round}
.cw{fill:#e6e6e6;stroke:#999;stroke-width:1}
.stop{stroke:#d00;stroke-width:3}
.agent{fill:none;stroke:#2a2;stroke-width:1.5;opacity:.8}
.truth{fill:none;stroke:#000;stroke-width:1;stroke-dasharray:4 3}
.lab{fill:none;stroke:#1f5fd0;stroke-width:2.5;opacity:.8}
.road{fill:none;stroke:#f08000;stroke-width:2;opacity:.9}
.lab-trig{fill:#1f5fd0} .road-trig{fill:#f08000;stroke:#000;stroke-width:.5}
.err{fill:none;stroke:#a0f;stroke-width:1.5}
.lbl{font-size:10px;fill:#333}
.legend .k{display:inline-block;width:18px;height:4px;margin:0 4px 2px 10px;vertical-align:middle}
.legend .k.route{background:#bbb}.legend .k.stop{background:#d00}.legend .k.cw{background:#e6e6e6;border:1px solid #999}
.legend .k.lab{background:#1f5fd0}.legend .k.road{background:#f08000}.legend .k.truth{background:#000}
.legend .k.agent{background:#2a2}
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--site", default=str(ROOT / "maps" / "default"), help="site folder (route.yaml)")
    ap.add_argument("--lab", nargs="+", required=True, help="lab logs (lab_vehicle drive, director output)")
    ap.add_argument("--road", nargs="+", required=True, help="road logs (the live replay's recording files)")
    ap.add_argument("--out", required=True, help="folder for report.txt and report.html")
    a = ap.parse_args(argv)
    for p in a.lab + a.road:
        if not pathlib.Path(p).is_file():
            ap.error(f"{p}: no such file")
    study = Study(a.site, Platform("lab", a.lab), Platform("road", a.road))
    parts = [f(study) for f in SECTIONS]
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    title = f"Crosswalk study on both platforms: {study.site.name}"
    txt = [title, "=" * len(title), f"lab:  {' '.join(study.lab.paths)}", f"road: {' '.join(study.road.paths)}", ""]
    for t, body, _ in parts:
        txt += [f"== {t}", body, ""]
    (out / "report.txt").write_text("\n".join(txt))
    body = "".join(f"<section><h2>{html.escape(t)}</h2>{h}</section>" for t, _, h in parts)
    (out / "report.html").write_text(
        f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title><style>{CSS}</style>'
        f'</head><body><h1>{html.escape(title)}</h1><p>lab: {html.escape(" ".join(study.lab.paths))}<br>road: '
        f'{html.escape(" ".join(study.road.paths))}</p>{body}</body></html>')
    print(f"report: {out / 'report.txt'}")
    print(f"report: {out / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
