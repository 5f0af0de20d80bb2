"""The webui bridge and its pages in real headless Chromium (Debian chromium + chromedriver):
pages draw on the default site, Proceed puts exactly one PARTICIPANT_INPUT on the bus per
press, an agent dragged in the editor and saved moves in the file (which passes
scenario-check and runs in the director), an illegal edit is shown and saves nothing, and
pages may publish only what they need. LCM ports 8021-8029, HTTP 18001-18009."""
import contextlib
import json
import re
import struct
import subprocess
import time
import urllib.error
import urllib.request

import pytest

from browser import assert_not_blank, screenshot
from conftest import BIN, ROOT, read_log, run
from webui_util import Bridge, Feeder, Listener, WsClient, chrome, site_copy, supervisor_msg, wait_for

LCM = "udpm://239.255.76.67:{}?ttl=0&recv_buf_size=8388608"


@pytest.fixture
def site(tmp_path):
    return site_copy(tmp_path)


def start(site, http_port, lcm_port):
    return Bridge(site, http_port, LCM.format(lcm_port))


def test_help_and_bad_site(tmp_path):
    p = run([BIN / "webui", "--help"])
    assert "--listen" in p.stdout and "127.0.0.1:8080" in p.stdout      # localhost unless told otherwise
    p = run([BIN / "webui", "--site", tmp_path / "nowhere"], check=False)
    assert p.returncode == 1 and "nowhere" in p.stderr


def test_bad_or_missing_map_is_named_and_pages_get_no_cloud(tmp_path):
    import sitedata
    site = site_copy(tmp_path)
    (site / "map.pcd").unlink()
    assert sitedata.Site(site).cloud_bytes() == sitedata.EMPTY_CLOUD          # a site without a map: no cloud
    (site / "map.pcd").write_text("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 10\nDATA binary\n" + "x" * 7)
    s = sitedata.Site(site)
    assert s.cloud_bytes() == sitedata.EMPTY_CLOUD and "map.pcd" in s._cloud_error   # truncated: named, not a crash
    with pytest.raises(sitedata.SiteError, match="site.yaml"):
        (site / "site.yaml").unlink()
        sitedata.Site(site)


@pytest.mark.live
def test_every_page_renders_on_the_default_site(site, tmp_path):
    b = start(site, 18001, 8021)
    feed = Feeder(b.lcm_url, pose_hz=50, agents_hz=20)
    feed.start()
    try:
        for page, size in (("operator", (1024, 600)), ("participant", (400, 760)), ("editor", (1280, 800))):
            png = screenshot(f"{b.url}/{page}", tmp_path / f"{page}.png", size=size, wait_ms=6000, timeout=120)
            assert_not_blank(png)
        # /view redraws at every new pose: under the helper's virtual time with software WebGL
        # that never settles, so its picture is taken in real time through chromedriver
        d = chrome((1024, 600))
        try:
            d.get(f"{b.url}/view")
            wait_for(lambda: "agents in range" in d.find_element("id", "info").text, 60, "view drawing")
            time.sleep(2)
            d.save_screenshot(str(tmp_path / "view.png"))
        finally:
            d.quit()
        assert_not_blank(tmp_path / "view.png")
        # and the live content is there, not only pixels
        d = chrome((1024, 600))
        try:
            d.get(f"{b.url}/operator")
            wait_for(lambda: "TRACKING" in d.find_element("id", "panel").text, what="operator shows the localizer")
            # heartbeats come at 1 Hz: the first may arrive a second after the pose
            wait_for(lambda: "lab_vehicle" in d.find_element("id", "panel").text, 5, "operator shows the heartbeats")
            text = d.find_element("id", "panel").text
            assert "km/h" in text and "lab_vehicle" in text and "next stop" in text
            # the supervisor's view: a command in a crash loop shows its state and restarts
            import lcm
            import portobello
            CS = portobello.command_state_t
            lc = lcm.LCM(b.lcm_url)
            sup = supervisor_msg(time.time_ns() // 1000, [("localizer", CS.STATE_RUNNING, 0, ""),
                                                          ("director", CS.STATE_BACKOFF, 3, "exit 1 <x>")])
            # the supervisor publishes at 1 Hz; the bridge advertises a channel at its first
            # message and the page subscribes then, so the first one is not relayed
            def shown():
                lc.publish("SUPERVISOR", sup.encode())
                return "SUPERVISOR ROAD" in d.find_element("id", "panel").text
            wait_for(shown, 5, "operator shows SUPERVISOR")
            text = d.find_element("id", "panel").text
            assert "BACKOFF ×3" in text and "RUNNING" in text, text
            assert d.execute_script("return [...document.querySelectorAll('#panel b.bad')]"
                                    ".some(e => e.textContent === 'BACKOFF ×3')")
            d.get(f"{b.url}/view")
            wait_for(lambda: "agents in range" in d.find_element("id", "info").text, what="view shows agents")
            # 12 agents staged, 10 within the render distance: the others are not drawn
            wait_for(lambda: "10 of 12 agents in range" in d.find_element("id", "info").text, what="render range applied")
        finally:
            d.quit()
    finally:
        feed.stop()
        b.stop()


@pytest.mark.live
def test_proceed_publishes_exactly_one_input_per_press(site):
    import portobello
    b = start(site, 18002, 8022)
    feed = Feeder(b.lcm_url, pose_hz=20, agents_hz=5, awaiting=True)
    feed.start()
    got = Listener(b.lcm_url, "PARTICIPANT_INPUT", portobello.participant_input_t)
    d = chrome((400, 760))
    try:
        d.get(f"{b.url}/participant")
        wait_for(lambda: d.find_element("id", "prompt").text == "Is now safe to proceed?", what="the prompt")
        button = d.find_element("id", "proceed")
        t_click = time.time_ns() // 1000
        button.click()
        wait_for(lambda: got.got, what="PARTICIPANT_INPUT")
        time.sleep(1.0)                          # anything else would have arrived by now
        assert len(got.got) == 1
        rx, m = got.got[0]
        assert (m.input, m.device, m.value) == ("proceed", "phone", 1)
        assert t_click - 200_000 < m.utime <= rx  # stamped with the press, not later than its arrival
        # a bouncing contact: two pointerdowns in the same instant are one press (real clicks under
        # this machine's load come 0.6 s apart, beyond the debounce, so the bounce is dispatched)
        time.sleep(0.7)
        d.execute_script("const b = document.getElementById('proceed');"
                         "for (let i = 0; i < 2; i++) b.dispatchEvent(new PointerEvent('pointerdown', {bubbles: true}));")
        time.sleep(1.0)
        assert len(got.got) == 2
        assert d.execute_script("return window.__participant.presses()") == 2
    finally:
        d.quit()
        got.stop()
        feed.stop()
        b.stop()


@pytest.mark.live
def test_pages_publish_only_what_they_need(site, tmp_path):
    import portobello
    b = start(site, 18003, 8023)
    got = Listener(b.lcm_url, "PARTICIPANT_INPUT", portobello.participant_input_t)
    try:
        # the operator page (and Foxglove on /ws) may not publish at all
        for path in ("/ws/operator", "/ws"):
            c = WsClient(b.ws.replace("/ws", path))
            info = c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "serverInfo")
            assert "clientPublish" not in info["capabilities"]
            c.send_json({"op": "advertise", "channels": [{"id": 1, "topic": "PARTICIPANT_INPUT", "encoding": "json", "schemaName": "x"}]})
            assert c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "status" and "not allowed" in m["message"])
            c.publish(1, {"input": "proceed", "value": 1, "press_ms": 0, "sent_ms": 0})
            c.close()
        # the participant page: PARTICIPANT_INPUT "proceed" only
        c = WsClient(b.ws + "/participant")
        c.send_json({"op": "advertise", "channels": [{"id": 1, "topic": "INITIAL_POSE", "encoding": "json", "schemaName": "x"},
                                                     {"id": 2, "topic": "PARTICIPANT_INPUT", "encoding": "json", "schemaName": "x"}]})
        assert c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "status" and "INITIAL_POSE" in m["message"])
        c.publish(2, {"input": "brake", "value": 1, "press_ms": 0, "sent_ms": 0})
        assert c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "status" and "brake" in m["message"])
        c.ws.send(struct.pack("<BIII", 2, 4, 1, 4) + b"json" + b'{"name": "x"}')       # a service call: editor only
        assert c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "status" and "not allowed" in m["message"])
        time.sleep(0.5)
        assert got.got == []
        c.publish(2, {"input": "proceed", "value": 1, "press_ms": 1000, "sent_ms": 1010})
        wait_for(lambda: got.got, what="the allowed input")
        c.close()
        # the editor writes only inside SITE/scenarios
        c = WsClient(b.ws + "/editor")
        before = sorted(p.name for p in site.rglob("*")) + sorted(p.name for p in tmp_path.iterdir())
        for bad in ("../evil", "/tmp/evil", "sub/evil", "..", ".hidden"):
            c.ws.send(struct.pack("<BIII", 2, 4, 7, 4) + b"json" + json.dumps({"name": bad, "model": {"scenario": "x"}}).encode())
            fail = c.recv_until(lambda m: isinstance(m, dict) and m.get("op") == "serviceCallFailure")
            assert fail and "refused" in fail["message"], bad
        assert sorted(p.name for p in site.rglob("*")) + sorted(p.name for p in tmp_path.iterdir()) == before
        c.close()
        # a page of another origin may not open the bus (a web site the phone visits, say)
        from websockets.exceptions import InvalidStatus
        with pytest.raises(InvalidStatus):
            WsClient(b.ws + "/participant", origin="http://evil.example")
    finally:
        got.stop()
        b.stop()


def _drag(d, canvas, start, dx, dy):
    from selenium.webdriver import ActionChains
    w, h = canvas.size["width"], canvas.size["height"]
    (ActionChains(d).move_to_element_with_offset(canvas, int(start[0] - w / 2), int(start[1] - h / 2))
     .click_and_hold().move_by_offset(dx // 2, dy // 2).move_by_offset(dx - dx // 2, dy - dy // 2).release().perform())


@contextlib.contextmanager
def _editor(site, http_port, lcm_port, scenario):
    """The bridge on the site and a browser on its editor, the scenario loaded and checked
    once; yields the browser and stops both after."""
    b = start(site, http_port, lcm_port)
    d = chrome((1280, 800))
    try:
        d.get(f"{b.url}/editor?scenario={scenario}")
        wait_for(lambda: d.execute_script("return window.__editor && window.__editor.model() !== null"), 40, "scenario loaded")
        wait_for(lambda: d.find_element("id", "checkstate").text.startswith("scenario-check:"), 40, "first check")
        time.sleep(0.5)
        yield d
    finally:
        d.quit()
        b.stop()


@pytest.mark.live
def test_editor_drag_agent_save_check_and_run(site, tmp_path):
    f = site / "scenarios" / "cw01_look_and_cross.yaml"
    before = f.read_text()
    with _editor(site, 18004, 8024, "cw01_look_and_cross") as d:
        assert d.find_element("id", "checkstate").text == "scenario-check: ok"
        canvas = d.find_element("id", "vtop")
        at = d.execute_script("return window.__editor.handleAt('agent:ped_a_phone')")
        mpp = d.execute_script("return window.__editor.mpp()")      # metres per CSS pixel of the top-down view
        _drag(d, canvas, at, 40, -20)
        wait_for(lambda: d.find_element("id", "checkstate").text == "scenario-check: ok", what="check after the drag")
        d.find_element("id", "save").click()
        wait_for(lambda: d.find_element("id", "savestate").text.startswith("saved"), what="saved")
    after = f.read_text()
    changed = [(a, c) for a, c in zip(before.splitlines(), after.splitlines()) if a != c]
    assert len(before.splitlines()) == len(after.splitlines()) and len(changed) == 1, changed
    old, new = changed[0]
    assert "ped_a_phone" in new
    xy = lambda line: [float(v) for v in re.search(r"start: \[([-\d.]+), ([-\d.]+)\]", line).groups()]
    (x0, y0), (x1, y1) = xy(old), xy(new)
    assert abs((x1 - x0) - 40 * mpp) < 0.5 and abs((y1 - y0) - 20 * mpp) < 0.5, (old, new)   # screen y is map -y
    assert [l for l in after.splitlines() if l.lstrip().startswith("#")] == [l for l in before.splitlines() if l.lstrip().startswith("#")]
    # the saved file passes scenario-check and runs in the director against the lab twin
    run([BIN / "scenario-check", "--site", site, f])
    lab, out = tmp_path / "lab.lcm", tmp_path / "dir.lcm"
    run([BIN / "lab_vehicle", "--site", site, "--out", lab, "--duration", 60, "--auto-proceed", 2])
    run([BIN / "director", "--site", site, "--scenario", f, "--replay", lab, "--out", out])
    import portobello
    first = None
    triggers = set()
    for ch, _, data in read_log(out, {"AGENTS", "SCENARIO_EVENT"}):
        if ch == "AGENTS" and first is None:
            first = {a.id: a.position for a in portobello.agents_t.decode(data).agents}
        elif ch == "SCENARIO_EVENT":
            e = portobello.scenario_event_t.decode(data)
            triggers.add(e.event_id) if e.kind == "trigger" else None
    assert abs(first["ped_a_phone"][0] - x1) < 1e-6 and abs(first["ped_a_phone"][1] - y1) < 1e-6
    assert {"car_approaches", "car_stopped"} <= triggers


@pytest.mark.live
def test_editor_illegal_edit_shows_error_and_saves_nothing(site):
    f = site / "scenarios" / "cw01_look_and_cross.yaml"
    before = f.read_bytes()
    with _editor(site, 18005, 8025, "cw01_look_and_cross") as d:
        canvas = d.find_element("id", "vtop")
        # select the approach volume in the list: the top-down view centres on it
        next(e for e in d.find_elements("css selector", "#list .item") if e.text == "approach").click()
        time.sleep(0.3)
        at = d.execute_script("return window.__editor.handleAt('vol:approach')")
        mpp = d.execute_script("return window.__editor.mpp()")
        # 200 px (30 m at the initial scale) sideways, off the road: the car's footprint never touches it
        _drag(d, canvas, at, -200, 0)
        assert 200 * mpp > 20
        wait_for(lambda: d.find_element("id", "checkstate").text == "scenario-check: errors", what="the error")
        issues = d.find_element("id", "issues").text
        assert "volume approach" in issues and "off the route" in issues, issues
        d.find_element("id", "save").click()
        wait_for(lambda: d.find_element("id", "savestate").text.startswith("not saved"), what="refusal")
    assert f.read_bytes() == before
    assert sorted(p.name for p in f.parent.iterdir()) == sorted(p.name for p in (ROOT / "maps/default/scenarios").iterdir())


@pytest.mark.live
def test_csharp_client_against_the_bridge(site, tmp_path):
    """The Unity client (modules/webui/unity/PortobelloClient.cs) compiled with Debian's mono
    and run against the bridge: poses and agents arrive converted to Unity's frame."""
    exe = tmp_path / "client.exe"
    run(["mcs", "-r:System.Runtime.Serialization.dll", f"-out:{exe}", ROOT / "modules/webui/unity/PortobelloClient.cs"])
    b = start(site, 18006, 8026)
    feed = Feeder(b.lcm_url, pose_hz=100, agents_hz=30)
    feed.start()
    try:
        p = run(["mono", exe, b.ws, 3], timeout=60)
    finally:
        feed.stop()
        b.stop()
    poses = re.findall(r"pose utime=\d+ unity_position=\(([-\d.]+), ([-\d.]+), ([-\d.]+)\) "
                       r"unity_rotation=\(([-\d.]+), ([-\d.]+), ([-\d.]+), ([-\d.]+)\) age_s=([-\d.]+)", p.stdout)
    assert len(poses) >= 2, p.stdout
    ux, uy, uz, qx, qy, qz, qw, age = map(float, poses[-1])
    # the feeder's car: map (x, -3.7, 0), yaw -0.036 rad -> Unity (x, 0, -3.7), rotation +2.06 deg about +Y
    assert 20.0 <= ux <= 170.0 and uy == 0.0 and uz == -3.7
    import math
    assert abs(qy - math.sin(0.018)) < 1e-4 and abs(qw - math.cos(0.018)) < 1e-4 and qx == 0.0 and qz == 0.0
    assert 0.0 <= age < 1.0
    agents = re.findall(r"agent (ped_\d+) pedestrian unity_position=\(([-\d.]+), ([-\d.]+), ([-\d.]+)\) heading_y=([-\d.]+)", p.stdout)
    last = {a[0]: tuple(map(float, a[1:])) for a in agents}
    assert len(last) == 12
    # ped_03: map (51, -9 + 0 * 6 = -9.0 ... see webui_util.agents_msg), yaw 0.9 rad -> heading_y -51.57 deg
    assert last["ped_03"] == (51.0, 0.0, -9.0, -51.57)
    assert int(re.search(r"messages=(\d+)", p.stdout).group(1)) > 50
