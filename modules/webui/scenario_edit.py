"""The staging editor's services (Foxglove protocol services, /ws/editor only).

A scenario travels to the page as plain data; edits come back as plain data and are
merged into the file's round-trip YAML tree (ruamel.yaml), so comments, flow style and
untouched numbers stay as they were. Every check runs the project's own
`scenario-check` on the merged text, so the page shows exactly what the tool says,
with the element each line belongs to. Files are written only inside SITE/scenarios/.
"""
import asyncio
import math
import io
import json
import os
import pathlib
import re
import struct
import tempfile

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq

ROOT = pathlib.Path(__file__).resolve().parents[2]
BIN = ROOT / "build" / "bin"
NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
SECTIONS = ("volumes", "agents", "behaviours", "triggers")
PREVIEW_HZ = 10

SERVICES = [{"id": i + 1, "name": f"scenario.{n}", "type": f"portobello/scenario_{n}",
             "requestSchema": "", "responseSchema": ""}
            for i, n in enumerate(("list", "load", "check", "save", "preview"))]


class EditError(Exception):
    pass


def yaml_rt():
    y = YAML()
    y.width = 4096
    y.preserve_quotes = True
    y.indent(mapping=2, sequence=4, offset=2)
    return y


def fresh(v):
    """New data as YAML nodes in the files' style: small maps and lists on one line."""
    if isinstance(v, dict):
        m = CommentedMap((k, fresh(x)) for k, x in v.items())
        if all(not isinstance(x, dict) and not (isinstance(x, list) and any(isinstance(i, dict) for i in x))
               for x in v.values()):
            m.fa.set_flow_style()
        return m
    if isinstance(v, list):
        s = CommentedSeq(fresh(x) for x in v)
        if all(not isinstance(x, dict) for x in v):
            s.fa.set_flow_style()
        return s
    return v


def merge(node, new):
    """Updates a round-trip node in place to equal `new`, keeping what did not change."""
    if isinstance(node, CommentedMap) and isinstance(new, dict):
        for k in [k for k in node if k not in new]:
            del node[k]
        for k, v in new.items():
            if k in node and isinstance(node[k], (CommentedMap, CommentedSeq)) and isinstance(v, (dict, list)):
                node[k] = merge(node[k], v)
            elif k not in node or node[k] != v or type(node[k]) is bool and type(v) is not bool:
                node[k] = fresh(v)
        return node
    if isinstance(node, CommentedSeq) and isinstance(new, list):
        while len(node) > len(new):
            del node[-1]
        for i, v in enumerate(new):
            if i >= len(node):
                node.append(fresh(v))
            elif isinstance(node[i], (CommentedMap, CommentedSeq)) and isinstance(v, (dict, list)):
                node[i] = merge(node[i], v)
            elif node[i] != v:
                node[i] = fresh(v)
        return node
    return fresh(new)


def element_of_line(doc, line):
    """'agent ped_a_main', 'trigger car_stopped', or a top-level key: what line (1-based) belongs to."""
    best = (-1, "")
    if not isinstance(doc, CommentedMap):
        return ""
    for k in doc:
        l0 = doc.lc.key(k)[0]
        if l0 < line and l0 > best[0]:
            best = (l0, k)
        if k in SECTIONS and isinstance(doc[k], CommentedSeq):
            for i, item in enumerate(doc[k]):
                l1 = doc[k].lc.item(i)[0]
                if l1 < line and l1 > best[0]:
                    ident = item.get("id", i) if isinstance(item, dict) else i
                    best = (l1, f"{k[:-1]} {ident}")
    return best[1]


LINE_RE = re.compile(r"^(?P<file>.+?):(?P<line>\d+): (?P<rest>.*)$")


class Editor:
    def __init__(self, site):
        self.site = site

    def path(self, name):
        """SITE/scenarios/NAME.yaml; anything that would land elsewhere is refused."""
        if not isinstance(name, str):
            raise EditError("scenario name missing")
        stem = name[:-5] if name.endswith(".yaml") else name
        if not NAME_RE.match(stem) or ".." in stem:
            raise EditError(f"scenario name {name!r} refused: letters, digits, _ - . only, no folders")
        folder = self.site.scenarios_dir.resolve()
        p = (folder / (stem + ".yaml")).resolve()
        if p.parent != folder:
            raise EditError(f"scenario {name!r} is outside {folder}")
        return p

    async def call(self, service_id, req):
        name = SERVICES[service_id - 1]["name"] if 0 < service_id <= len(SERVICES) else None
        if name == "scenario.list":
            return {"scenarios": sorted(p.stem for p in self.site.scenarios_dir.glob("*.yaml"))}
        if name == "scenario.load":
            p = self.path(req.get("name"))
            text = p.read_text()
            return {"name": p.stem, "text": text, "model": json.loads(json.dumps(yaml_rt().load(text)))}
        if name == "scenario.check":
            text, doc = self.merged(req)
            return {"text": text, **(await self.check(text, doc, req["name"]))}
        if name == "scenario.save":
            return await self.save(req)
        if name == "scenario.preview":
            return await self.preview(req)
        raise EditError(f"unknown service {service_id}")

    def merged(self, req):
        p = self.path(req.get("name"))
        y = yaml_rt()
        doc = y.load(p.read_text()) if p.is_file() else CommentedMap()
        doc = merge(doc, req.get("model") or {})
        out = io.StringIO()
        y.dump(doc, out)
        text = out.getvalue()
        return text, y.load(text)

    async def check(self, text, doc, name):
        with tempfile.TemporaryDirectory(prefix="webui-check-") as tmp:
            f = pathlib.Path(tmp) / (pathlib.Path(name).stem + ".yaml")
            f.write_text(text)
            proc = await asyncio.create_subprocess_exec(str(BIN / "scenario-check"), "--site", str(self.site.dir), str(f),
                                                        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
            out, _ = await proc.communicate()
        issues = []
        for line in out.decode(errors="replace").splitlines():
            m = LINE_RE.match(line)
            if not m:
                continue
            rest, sev = m["rest"], None
            if rest.startswith(("error: ", "warning: ")):
                sev, rest = rest.split(": ", 1)
            elif rest.endswith(": error"):
                sev, rest = "error", rest[:-len(": error")]
            if sev:
                ln = int(m["line"])
                issues.append({"severity": sev, "line": ln, "element": element_of_line(doc, ln), "message": rest})
        if proc.returncode != 0 and not any(i["severity"] == "error" for i in issues):
            issues.append({"severity": "error", "line": 0, "element": "", "message": out.decode(errors="replace").strip()})
        return {"ok": proc.returncode == 0, "issues": issues}

    async def save(self, req):
        text, doc = self.merged(req)
        result = await self.check(text, doc, req["name"])
        if not result["ok"]:
            return {"saved": False, **result}
        p = self.path(req["name"])
        tmp = p.with_name(f".{p.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, p)
        return {"saved": True, "path": str(p.relative_to(self.site.dir.parent)), **result}

    async def preview(self, req):
        """The scenario against the lab twin: an offline lab drive, the director replayed on it;
        the car and the agents sampled at PREVIEW_HZ for the page's time slider."""
        import lcm
        import portobello
        text, doc = self.merged(req)
        duration = min(max(float(req.get("duration_s", 120)), 5.0), 600.0)
        with tempfile.TemporaryDirectory(prefix="webui-preview-") as tmp:
            sc = pathlib.Path(tmp) / (pathlib.Path(req["name"]).stem + ".yaml")
            sc.write_text(text)
            lab, out = pathlib.Path(tmp) / "lab.lcm", pathlib.Path(tmp) / "director.lcm"
            for cmd in ([BIN / "lab_vehicle", "--site", self.site.dir, "--out", lab, "--duration", duration,
                         "--auto-proceed", "2"],
                        [BIN / "director", "--site", self.site.dir, "--scenario", sc, "--replay", lab, "--out", out]):
                proc = await asyncio.create_subprocess_exec(*map(str, cmd), stdout=asyncio.subprocess.PIPE,
                                                            stderr=asyncio.subprocess.STDOUT)
                msg, _ = await proc.communicate()
                if proc.returncode != 0:
                    raise EditError(f"{pathlib.Path(cmd[0]).name}: {msg.decode(errors='replace').strip()[-400:]}")
            step = 1_000_000 // PREVIEW_HZ
            car, agents, events, t0 = [], [], [], None
            next_car = next_agents = None
            for path in (lab, out):
                for ev in lcm.EventLog(str(path), "r"):
                    if ev.channel == "POSE" and path == lab:
                        m = portobello.pose_t.decode(ev.data)
                        t0 = m.utime if t0 is None else t0
                        if next_car is None or m.utime >= next_car:
                            next_car = m.utime + step
                            w, x, y, z = m.orientation
                            yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
                            car.append([(m.utime - t0) / 1e6, round(m.position[0], 3), round(m.position[1], 3), round(yaw, 4)])
                    elif ev.channel == "AGENTS":
                        m = portobello.agents_t.decode(ev.data)
                        if next_agents is None or m.utime >= next_agents:
                            next_agents = m.utime + step
                            agents.append([(m.utime - t0) / 1e6,
                                           [[a.id, round(a.position[0], 3), round(a.position[1], 3), round(a.yaw_rad, 4),
                                             a.animation, a.kind] for a in m.agents]])
                    elif ev.channel == "SCENARIO_EVENT":
                        m = portobello.scenario_event_t.decode(ev.data)
                        events.append([(m.utime - t0) / 1e6, m.kind, m.event_id, m.agent_id])
        return {"duration_s": duration, "car": car, "agents": agents, "events": events}


def call_frame(service_id, call_id, payload):
    """A service call request as the protocol frames it (used by tests)."""
    enc = b"json"
    return struct.pack("<BIII", 2, service_id, call_id, len(enc)) + enc + payload
