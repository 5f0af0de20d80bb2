"""What the webui tests and `make bench-webui` share: starting the bridge on its own ports,
a chromedriver session on Debian's chromium (no browser download), a bus feeder that
publishes like the car, and a Foxglove-protocol client for the security checks."""
import json
import math
import pathlib
import shutil
import struct
import subprocess
import sys
import threading
import time
import urllib.request

from conftest import BIN, ROOT, wait_for  # noqa: F401 (wait_for: for the pages' tests and benches)
from browser import CHROMIUM

CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
SUBPROTOCOL = "foxglove.websocket.v1"


def site_copy(tmp_path):
    """The default site in tmp (scenarios copied so the editor may write them; the map linked)."""
    site = tmp_path / "site"
    src = ROOT / "maps" / "default"
    site.mkdir()
    for f in src.iterdir():
        if f.name == "map.pcd":
            (site / f.name).symlink_to(f)
        elif f.is_dir():
            shutil.copytree(f, site / f.name)
        else:
            shutil.copy(f, site / f.name)
    return site


class Bridge:
    def __init__(self, site, http_port, lcm_url, extra=()):
        self.url = f"http://127.0.0.1:{http_port}"
        self.ws = f"ws://127.0.0.1:{http_port}/ws"
        self.lcm_url = lcm_url
        self.proc = subprocess.Popen([str(BIN / "webui"), "--site", str(site), "--listen", f"127.0.0.1:{http_port}",
                                      "--lcm-url", lcm_url, *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        deadline = time.time() + 30
        while True:
            try:
                urllib.request.urlopen(self.url + "/api/site", timeout=1).read()
                break
            except OSError:
                if self.proc.poll() is not None or time.time() > deadline:
                    raise AssertionError(f"webui did not start:\n{self.proc.stdout.read() if self.proc.poll() is not None else ''}")
                time.sleep(0.2)

    def rss_kb(self):
        # the bridge is the wrapper's exec'd python: same pid
        for line in pathlib.Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        return 0

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def chrome(size=(1280, 900)):
    """A chromedriver session on Debian's chromium, headless, software WebGL."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
              "--disable-dev-shm-usage", "--no-first-run", "--disable-extensions", f"--window-size={size[0]},{size[1]}"):
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)


# ---------------------------------------------------------------- the bus
def _types():
    import portobello
    return portobello


def pose_msg(t_us, x, y, yaw, v=5.0):
    pb = _types()
    p = pb.pose_t()
    p.utime = t_us
    p.position = [x, y, 0.0]
    p.orientation = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    p.velocity = [v * math.cos(yaw), v * math.sin(yaw), 0.0]
    p.angular_velocity = [0.0, 0.0, 0.0]
    p.covariance = [0.0] * 36
    p.status = pb.pose_t.STATUS_TRACKING
    p.source = pb.pose_t.SOURCE_PREDICTED
    p.match_score = float("nan")
    return p


def agents_msg(t_us, n=12, scenario="crosswalk_study"):
    pb = _types()
    m = pb.agents_t()
    m.utime = t_us
    m.scenario = scenario
    for i in range(n):
        a = pb.agent_t()
        a.id = f"ped_{i:02d}"
        a.kind = "pedestrian"
        a.model = "ped_adult_m1"
        a.position = [45.0 + 2.0 * i, -9.0 + (i % 3) * 6.0, 0.0]
        a.yaw_rad = 0.3 * i
        a.velocity = [1.4, 0.0, 0.0]
        a.animation = "walk" if i % 2 else "idle"
        a.animation_phase = 0.1 * (i % 10)
        a.in_render_range = i < 10
        a.distance_m = 10.0 + i
        m.agents.append(a)
    m.nagents = n
    return m


def status_msg(t_us, module, counters=None, state=1):
    pb = _types()
    s = pb.status_t()
    s.utime = t_us
    s.module = module
    s.pid = 1
    s.state = state
    s.counter_names = list((counters or {}).keys())
    s.counter_values = list((counters or {}).values())
    s.ncounters = len(s.counter_names)
    s.last_error = ""
    return s


def supervisor_msg(t_us, commands):
    """SUPERVISOR of stack "road" with (name, state, restarts, detail) per command."""
    pb = _types()
    m = pb.supervisor_t()
    m.utime, m.stack, m.config_path, m.pid = t_us, "road", "stacks/road.yaml", 1
    for name, state, restarts, detail in commands:
        c = pb.command_state_t()
        c.name, c.group, c.state, c.pid, c.restarts, c.detail = name, "road", state, 2, restarts, detail
        c.last_exit = pb.command_state_t.EXIT_NONE
        c.output_path = ""
        m.commands.append(c)
    m.ncommands = len(m.commands)
    return m


class Feeder(threading.Thread):
    """Publishes POSE_PREDICTED at pose_hz, POSE at 10 Hz, AGENTS (12 agents) at agents_hz and
    STATUS of lab_vehicle / localizer / director at 1 Hz, each stamped with the wall clock
    when published (so a page can tell how long the message took)."""

    def __init__(self, lcm_url, pose_hz=200, agents_hz=60, awaiting=True, duration=None):
        super().__init__(daemon=True)
        import lcm
        self.lc = lcm.LCM(lcm_url)
        self.pose_hz, self.agents_hz, self.awaiting, self.duration = pose_hz, agents_hz, awaiting, duration
        self.stop_flag = False
        self.sent = {"POSE_PREDICTED": 0, "AGENTS": 0}

    def run(self):
        t0 = time.monotonic()
        period = 1.0 / self.pose_hz
        k = 0
        next_agents = next_status = next_pose = 0.0
        while not self.stop_flag and (self.duration is None or time.monotonic() - t0 < self.duration):
            target = t0 + k * period
            now = time.monotonic()
            if target > now:
                time.sleep(target - now)
            now = time.monotonic() - t0
            t_us = time.time_ns() // 1000
            x = 20.0 + 5.0 * (now % 30)
            p = pose_msg(t_us, x, -3.7, -0.036)
            self.lc.publish("POSE_PREDICTED", p.encode())
            self.sent["POSE_PREDICTED"] += 1
            if now >= next_pose:
                next_pose = now + 0.1
                p.source = 0
                self.lc.publish("POSE", p.encode())
            if now >= next_agents:
                next_agents += 1.0 / self.agents_hz
                self.lc.publish("AGENTS", agents_msg(time.time_ns() // 1000).encode())
                self.sent["AGENTS"] += 1
            if now >= next_status:
                next_status = now + 1.0
                for mod, c in (("lab_vehicle", {"awaiting_proceed": int(self.awaiting)}), ("localizer", {}), ("director", {})):
                    self.lc.publish("STATUS", status_msg(t_us, mod, c).encode())
            k += 1

    def stop(self):
        self.stop_flag = True
        self.join(5)


class Listener(threading.Thread):
    """Collects (wall receive us, decoded) for one channel."""

    def __init__(self, lcm_url, channel, cls):
        super().__init__(daemon=True)
        import lcm
        self.lc = lcm.LCM(lcm_url)
        self.got = []
        self.stop_flag = False
        self.lc.subscribe(channel, lambda ch, data: self.got.append((time.time_ns() // 1000, cls.decode(data))))
        self.start()

    def run(self):
        while not self.stop_flag:
            self.lc.handle_timeout(50)

    def stop(self):
        self.stop_flag = True
        self.join(2)


# ---------------------------------------------------------------- a protocol client
class WsClient:
    """A minimal Foxglove-protocol client (websockets' sync client) for checks from Python."""

    def __init__(self, url, subprotocol=SUBPROTOCOL, **kw):
        from websockets.sync.client import connect
        self._cm = connect(url, subprotocols=[subprotocol], max_size=None, **kw)
        self.ws = self._cm.__enter__()
        self.texts = []

    def send_json(self, obj):
        self.ws.send(json.dumps(obj))

    def recv_until(self, pred, timeout=5.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            try:
                m = self.ws.recv(timeout=max(0.01, deadline - time.time()))
            except TimeoutError:
                break
            if isinstance(m, str):
                m = json.loads(m)
                self.texts.append(m)
            if pred(m):
                return m
        return None

    def publish(self, chan_id, obj):
        self.ws.send(struct.pack("<BI", 1, chan_id) + json.dumps(obj).encode())

    def close(self):
        self._cm.__exit__(None, None, None)


sys.path.insert(0, str(ROOT / "modules" / "webui"))
