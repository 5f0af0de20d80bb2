#!/usr/bin/env python3
"""The README's pictures of the pages, from a live lab session: lab_vehicle and the director
(crosswalk_study) on a private bus, the bridge, and headless Chromium once the twin waits
for proceed at its first stop line. Usage: screenshots.py OUT_DIR"""
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "build" / "python"))
from browser import assert_not_blank  # noqa: E402
from webui_util import Bridge, Listener, chrome, wait_for  # noqa: E402

BIN = ROOT / "build" / "bin"
URL = "udpm://239.255.76.67:8027?ttl=0&recv_buf_size=8388608"


def main():
    out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "docs")
    import portobello
    site = ROOT / "maps" / "default"
    procs = [subprocess.Popen([BIN / "director", "--site", site, "--scenario", "crosswalk_study", "--lcm-url", URL],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
             subprocess.Popen([BIN / "lab_vehicle", "--site", site, "--lcm-url", URL], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    bridge = Bridge(site, 18007, URL)
    lab = Listener(URL, "LAB_EVENT", portobello.scenario_event_t)
    try:
        wait_for(lambda: any(e.event_id == "awaiting_proceed" for _, e in lab.got), 120, "the twin at its first stop line")
        time.sleep(1.0)
        for page, size in (("operator", (1024, 600)), ("participant", (390, 700)), ("editor", (1280, 720)), ("view", (1024, 600))):
            d = chrome(size)      # real time (the pages show live ages), not the helper's virtual time
            try:
                d.get(f"{bridge.url}/{page}?scenario=cw01_look_and_cross")
                time.sleep(8)
                png = out / f"webui-{page}.png"
                d.save_screenshot(str(png))
            finally:
                d.quit()
            assert_not_blank(png)
            print(png)
    finally:
        lab.stop()
        bridge.stop()
        for p in procs:
            p.terminate()
            p.wait(10)


if __name__ == "__main__":
    main()
