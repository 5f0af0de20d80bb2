"""Shared pytest set-up: paths, the generated `portobello` types, log reading.

Tests marked `real` read ../shared/data (captures whose licence keeps them out of
the project). They run only with `make test-real` (pytest -m real) or PB_REAL=1,
and skip with a message when the data is absent.

Tests marked `live` run processes in real time (a live LCM bus, a page talking to it):
`make test` runs every other test first, on every core (pytest-xdist, one module per
worker), then these, two modules at a time, so no CPU-bound work slows them. A new test
that runs anything live must carry the mark and use ports no other test uses.
"""
import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
BUILD = ROOT / "build"
BIN = BUILD / "bin"
SHARED_DATA = ROOT.parent / "shared" / "data"
VEHICLE = ROOT / "vehicles" / "prius2017.yaml"   # the default vehicle (simdrive, lab_vehicle)
sys.path.insert(0, str(BUILD / "python"))


def pytest_configure(config):
    config.addinivalue_line("markers", "real: needs ../shared/data (run with make test-real)")
    config.addinivalue_line("markers", "live: runs in real time (a live bus, a browser page that "
                            "talks to it): `make test` runs these after the others, two modules at a time")


def pytest_collection_modifyitems(config, items):
    if "real" in (config.getoption("-m") or "") or os.environ.get("PB_REAL") == "1":
        return
    skip = pytest.mark.skip(reason="real-data test: run `make test-real`")
    for item in items:
        if "real" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="module")
def tmp(request, tmp_path_factory):
    """A scratch folder shared by one test module's fixtures (named after the module)."""
    return tmp_path_factory.mktemp(request.module.__name__.removeprefix("test_"))


MULRAN = SHARED_DATA / "lidar_seq_mulran_riverside02_part1"


@pytest.fixture(scope="session")
def mulran_reference(tmp_path_factory):
    """The MulRan keyframes' refined reference (reference.py, one thread: the same file every
    build) and its report (the keyframes it judges implausible); made once a session."""
    if not MULRAN.exists():
        pytest.skip(f"{MULRAN} is absent (real data lives in ../shared/data)")
    d = tmp_path_factory.mktemp("mulran")
    run([sys.executable, ROOT / "modules/localizer/bench/reference.py", "--scans", MULRAN / "Scans",
         "--poses", MULRAN / "optimized_poses.txt", "--times", MULRAN / "times.txt", "--threads", "1",
         "--out", d / "refined_poses.txt", "--report", d / "report.json"], timeout=900)
    report = json.loads((d / "report.json").read_text())
    return {"poses": d / "refined_poses.txt", "report": report, "implausible": report["implausible_keyframes_refined"]}


@pytest.fixture(scope="module")
def vehicle():
    """The default vehicle's parameters (vehicles/prius2017.yaml) as a dict."""
    import yaml
    return yaml.safe_load(VEHICLE.read_text())


def read_log(path, channels=None):
    """Yields (channel, timestamp_us, data) for every event of an LCM log."""
    import lcm
    log = lcm.EventLog(str(path), "r")
    for ev in log:
        if channels is None or ev.channel in channels:
            yield ev.channel, ev.timestamp, ev.data


def interrupt(proc, timeout=10):
    """Stops a live process as Ctrl-C does (SIGINT) and waits for it; returns its
    (stdout, stderr). The caller still kills it in a `finally` if anything failed before."""
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=timeout)


def wait_for(fn, timeout=20, what="condition", period=0.1, state=None):
    """Polls fn every period seconds until it returns something true, and returns that; after
    timeout seconds raises AssertionError naming what (and state(), when given)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = fn()
        if v:
            return v
        time.sleep(period)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}" + (f"; state:\n{state()}" if state else ""))


def run(args, check=True, **kw):
    """Runs a project binary; returns the CompletedProcess (text output)."""
    args = [str(a) for a in args]
    p = subprocess.run(args, capture_output=True, text=True, **kw)
    if check and p.returncode != 0:
        raise AssertionError(f"{' '.join(args)} exited {p.returncode}\nstdout:\n{p.stdout}\nstderr:\n{p.stderr}")
    return p
