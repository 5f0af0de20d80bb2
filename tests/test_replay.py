"""The replay driver, through a real tool (log-summary): log order and log time,
deterministic output, and a truncated or corrupt log stopping with the byte
offset while everything already written stays readable."""
import math
import shutil

import pytest

import portobello
from conftest import BIN, interrupt, read_log, run

T0 = 1_714_572_000_000_000  # 2024-05-01 14:00 UTC


def write_drive(path, seconds=5.0):
    """GROUND_TRUTH at 100 Hz: 3 s at 10 m/s along x, then standing still; IMU at 200 Hz."""
    import lcm
    log = lcm.EventLog(str(path), "w", overwrite=True)
    n = 0
    for i in range(int(seconds * 200)):
        t = T0 + i * 5000
        if i % 2 == 0:
            p = portobello.pose_t()
            p.utime = t
            tt = i * 0.005
            p.position = [10.0 * min(tt, 3.0), 0.0, 0.0]
            p.orientation = [1.0, 0.0, 0.0, 0.0]
            p.velocity = [10.0 if tt < 3.0 else 0.0, 0.0, 0.0]
            p.angular_velocity = [0.0] * 3
            p.covariance = [0.0] * 36
            p.source = portobello.pose_t.SOURCE_GROUND_TRUTH
            p.match_score = math.nan
            log.write_event(t, "GROUND_TRUTH", p.encode())
            n += 1
        m = portobello.imu_t()
        m.utime = t
        m.accel = [0.0, 0.0, 9.81]
        m.gyro = [0.0] * 3
        log.write_event(t, "IMU", m.encode())
        n += 1
    log.close()
    return n


def status_messages(path):
    return [portobello.status_t.decode(d) for ch, _, d in read_log(path) if ch == "STATUS"]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    n = write_drive(d / "in.lcm")
    return d, n


def test_summary_of_a_log(drive):
    d, n = drive
    p = run([BIN / "log-summary", "--replay", d / "in.lcm", "--out", d / "out.lcm"])
    assert "GROUND_TRUTH" in p.stdout and "IMU" in p.stdout
    line = [l for l in p.stdout.splitlines() if l.startswith("GROUND_TRUTH")][0].split()
    assert int(line[1]) == 500 and abs(float(line[2]) - 100.0) < 0.5
    line = [l for l in p.stdout.splitlines() if l.startswith("IMU")][0].split()
    assert int(line[1]) == 1000 and abs(float(line[2]) - 200.0) < 0.5
    assert "30.0 m driven" in p.stdout
    assert "1 stops" in p.stdout
    # STATUS once per second of log time (at 1, 2, 3, 4 s) plus the final one.
    st = status_messages(d / "out.lcm")
    assert len(st) == 5
    # Each heartbeat fires before the first event at its deadline: module time is the newest input before it.
    assert [s.utime for s in st[:4]] == [T0 + k * 1_000_000 - 5000 for k in (1, 2, 3, 4)]
    final = st[-1]
    assert final.module == "log-summary" and final.pid == 0
    counts = {i.channel: i.count for i in final.inputs}
    assert counts == {"GROUND_TRUTH": 500, "IMU": 1000}
    assert final.state == portobello.status_t.STATE_STOPPING


def test_replay_is_deterministic(drive, tmp_path):
    d, _ = drive
    run([BIN / "log-summary", "--replay", d / "in.lcm", "--out", tmp_path / "a.lcm"])
    run([BIN / "log-summary", "--replay", d / "in.lcm", "--out", tmp_path / "b.lcm"])
    assert (tmp_path / "a.lcm").read_bytes() == (tmp_path / "b.lcm").read_bytes()


def event_offsets(path):
    """Byte offset of every event header, walked from the format."""
    data, offs, i = path.read_bytes(), [], 0
    while i < len(data):
        offs.append(i)
        ch = int.from_bytes(data[i + 20:i + 24], "big")
        ln = int.from_bytes(data[i + 24:i + 28], "big")
        i += 28 + ch + ln
    return offs


def test_corrupt_log_stops_with_byte_offset_and_keeps_output(drive, tmp_path):
    d, n = drive
    offs = event_offsets(d / "in.lcm")
    assert len(offs) == n
    bad_event = 1000  # past 3.3 s of log time: STATUS at 1, 2, 3 s is already out
    src = tmp_path / "bad.lcm"
    data = bytearray((d / "in.lcm").read_bytes())
    data[offs[bad_event]:offs[bad_event] + 4] = b"JUNK"
    src.write_bytes(bytes(data))
    p = run([BIN / "log-summary", "--replay", src, "--out", tmp_path / "out.lcm"], check=False)
    assert p.returncode == 1
    assert f"bad.lcm: byte {offs[bad_event]}:" in p.stderr
    assert f"stopped after {bad_event} events" in p.stderr
    # Everything written before the damage is there and readable, plus the final STATUS.
    st = status_messages(tmp_path / "out.lcm")
    assert len(st) == 4
    assert st[-1].state == portobello.status_t.STATE_ERROR
    assert f"byte {offs[bad_event]}" in st[-1].last_error
    assert sum(i.count for i in st[-1].inputs) == bad_event


def test_torn_last_event_replays_up_to_the_cut_with_a_warning(drive, tmp_path):
    """A recording cut by a power loss ends inside its last event: the replay reads
    everything before it, warns with the byte offset, and exits 0 (the data is the study's)."""
    d, n = drive
    offs = event_offsets(d / "in.lcm")
    cut = 1000
    src = tmp_path / "torn.lcm"
    src.write_bytes((d / "in.lcm").read_bytes()[:offs[cut] + 17])
    p = run([BIN / "log-summary", "--replay", src, "--out", tmp_path / "out.lcm"], check=False)
    assert p.returncode == 0, p.stderr
    assert f"torn.lcm: byte {offs[cut]}: warning: the last event is torn (17 of its" in p.stderr
    st = status_messages(tmp_path / "out.lcm")
    assert len(st) == 4
    assert st[-1].state == portobello.status_t.STATE_STOPPING
    assert sum(i.count for i in st[-1].inputs) == cut


def test_bad_arguments(tmp_path):
    p = run([BIN / "log-summary", "--replay", tmp_path / "missing.lcm", "--out", tmp_path / "o.lcm"], check=False)
    assert p.returncode == 1 and "missing.lcm: cannot open" in p.stderr
    p = run([BIN / "log-summary", "--replay", tmp_path / "x.lcm"], check=False)
    assert p.returncode == 2 and "--replay and --out go together" in p.stderr
    p = run([BIN / "log-summary", "--help"])
    assert "usage: log-summary" in p.stdout


@pytest.mark.live
def test_live_bus_and_clean_stop_on_signal():
    """log-summary on the live bus (real UDP multicast, private port, ttl=0): it counts
    what Python publishes and prints the summary after SIGINT."""
    import lcm
    import subprocess
    import time
    url = "udpm://239.255.76.67:7742?ttl=0&recv_buf_size=8388608"
    proc = subprocess.Popen([str(BIN / "log-summary"), "--lcm-url", url],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(0.5)  # let it subscribe
        lc = lcm.LCM(url)
        for i in range(50):
            m = portobello.imu_t()
            m.utime = T0 + i * 5000
            m.accel = [0.0, 0.0, 9.81]
            m.gyro = [0.0] * 3
            lc.publish("IMU", m.encode())
            time.sleep(0.002)
        time.sleep(0.5)
        out, err = interrupt(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "listening on " + url in err
    line = [l for l in out.splitlines() if l.startswith("IMU")][0].split()
    assert int(line[1]) == 50
