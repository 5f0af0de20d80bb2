"""modules/can: candump captures and CAN_FRAME logs -> CAN_FRAME + VEHICLE_SPEED.

Fast tests use the real RAV4 sample committed in tests/data/can_rav4 (comma2k19,
2 s, 4,516 frames) with comma's own decoded wheel speeds, a simdrive drive (Prius
frames), and small captures written here for bad input. The `real` test runs the
full 60 s RAV4 segment of ../shared/data. The SocketCAN path cannot run on this
kernel (no AF_CAN); its frame conversion is covered by build/tests/test_can."""
import math
import struct

import numpy as np
import pytest

import portobello
from conftest import BIN, BUILD, ROOT, SHARED_DATA, interrupt, read_log, run

DATA = ROOT / "tests" / "data" / "can_rav4"
SAMPLE = DATA / "rav4_seg40_first2s.candump.log"
SAMPLE_REF = DATA / "can_speed_wheelspeeds_mps_first2s.csv"
RAV4 = ROOT / "vehicles" / "rav4hybrid2017.yaml"
DBC_DIR = ROOT / "vehicles" / "dbc"
KMH = 3.6


def speeds(path, event_time_is_utime=True):
    out = []
    for ch, ts, data in read_log(path, {"VEHICLE_SPEED"}):
        m = portobello.vehicle_speed_t.decode(data)
        assert ts == m.utime or not event_time_is_utime
        out.append(m)
    return out


def frames(path):
    return [portobello.can_frame_t.decode(d) for _, _, d in read_log(path, {"CAN_FRAME"})]


def last_status(path):
    st = [portobello.status_t.decode(d) for _, _, d in read_log(path, {"STATUS"})]
    assert st, "no STATUS in " + str(path)
    s = st[-1]
    assert s.module == "can"
    return dict(zip(s.counter_names, s.counter_values)), s


def wheel_rows(vs):
    return [m for m in vs if m.source == "WHEEL_SPEEDS"]


def check_against_comma(vs, ref_csv):
    ref = np.genfromtxt(ref_csv, delimiter=",", names=True)
    ws = wheel_rows(vs)
    assert len(ws) == len(ref)                       # one VEHICLE_SPEED per 0x0AA frame, none lost
    t = np.array([m.utime for m in ws], dtype=np.int64)
    assert np.array_equal(t, np.round(ref["t_unix"] * 1e6).astype(np.int64))
    got = np.array([m.wheel_speed_mps for m in ws])
    want = np.stack([ref["ws_fl_mps"], ref["ws_fr_mps"], ref["ws_rl_mps"], ref["ws_rr_mps"]], axis=1)
    err_kmh = np.abs(got - want) * KMH
    assert err_kmh.max() < 0.01, err_kmh.max()
    assert (np.abs(np.array([m.speed_mps for m in ws]) - ref["speed_mps"]) * KMH).max() < 0.01
    assert all(m.has_wheel_speeds for m in ws)
    return err_kmh.max(), len(ws)


# ---------------------------------------------------------------- the RAV4 sample

def test_rav4_sample_candump(tmp_path):
    out = tmp_path / "rav4.lcm"
    p = run([BIN / "can", "--candump", SAMPLE, "--out", out, "--vehicle", RAV4])
    lines = SAMPLE.read_text().splitlines()
    fr = frames(out)
    # every frame kept, in file order, as import-candump would write it
    assert len(fr) == len(lines) == 4516
    ref_frames = tmp_path / "import.lcm"
    run([BIN / "import-candump", "--in", SAMPLE, "--out", ref_frames, "--quiet"])
    assert [(f.utime, f.bus, f.id, bytes(f.data)) for f in fr] == \
        [(f.utime, f.bus, f.id, bytes(f.data)) for f in frames(ref_frames)]
    vs = speeds(out)
    check_against_comma(vs, SAMPLE_REF)
    sp = [m for m in vs if m.source == "SPEED"]
    assert len(sp) == sum(1 for line in lines if " can0 0B4#" in line) == 83
    assert all(not m.has_wheel_speeds for m in sp)
    # the RAV4 sends its yaw rate (KINEMATICS 0x024 at ~83 Hz): every record carries one
    assert all(m.has_yaw_rate for m in vs[1:]) and all(abs(m.yaw_rate_rps) < 0.2 for m in vs if m.has_yaw_rate)
    # timestamps monotonic, in the events and in the messages
    ts = [t for _, t, _ in read_log(out)]
    assert ts == sorted(ts)
    assert [m.utime for m in vs] == sorted(m.utime for m in vs)
    counters, st = last_status(out)
    assert counters["frames"] == 4516 and counters["speed"] == len(vs)
    assert counters.get("bad_checksum", 0) == 0
    # the data's own quirks, counted with their reason (tests/data/can_rav4/NOTICE: comma's
    # numpy export stripped trailing zero bytes; 0x262 was padded to another DBC's length)
    assert counters["bad_length"] == 133
    assert counters["unknown_id"] == 731 and counters["other_bus"] == 2723
    assert f"{SAMPLE}:84: id 0x228 ACCELEROMETER: 4 bytes, the DBC says 8" in p.stderr
    assert "4516 frames" in p.stderr and "133 bad length" in p.stderr


def test_rav4_replay_matches_candump(tmp_path):
    """--replay of import-candump's log gives the very same VEHICLE_SPEED messages."""
    a, frames_log, b = tmp_path / "a.lcm", tmp_path / "frames.lcm", tmp_path / "b.lcm"
    run([BIN / "can", "--candump", SAMPLE, "--out", a, "--vehicle", RAV4])
    run([BIN / "import-candump", "--in", SAMPLE, "--out", frames_log, "--quiet"])
    run([BIN / "can", "--replay", frames_log, "--out", b, "--vehicle", RAV4])
    va = [(t, d) for _, t, d in read_log(a, {"VEHICLE_SPEED"})]
    vb = [(t, d) for _, t, d in read_log(b, {"VEHICLE_SPEED"})]
    assert len(va) == 249 and va == vb
    assert not list(read_log(b, {"CAN_FRAME"}))      # replay does not echo its input
    # deterministic: byte-identical output on a second run
    c = tmp_path / "c.lcm"
    run([BIN / "can", "--replay", frames_log, "--out", c, "--vehicle", RAV4])
    assert b.read_bytes() == c.read_bytes()


@pytest.mark.parametrize("dbc", ["toyota_prius_2017_pt_generated.dbc", "toyota_rav4_hybrid_2017_pt_generated.dbc"])
def test_dbc_decoding_matches_cantools(dbc):
    """Every signal of every frame of the sample whose id and length the DBC knows,
    decoded by our DBC reader and by cantools: the same values."""
    import cantools
    db = cantools.database.load_file(str(DBC_DIR / dbc), strict=False)
    out = run([BUILD / "tests" / "can_signal_dump", DBC_DIR / dbc, SAMPLE]).stdout.splitlines()
    ours = {}
    for line in out:
        n, _, _, sig, val = line.split()
        ours[(int(n), sig)] = float(val)
    ref = {}
    for n, line in enumerate(SAMPLE.read_text().splitlines(), 1):
        fid, data = line.split()[2].split("#")
        try:
            msg = db.get_message_by_frame_id(int(fid, 16))
        except KeyError:
            continue
        data = bytes.fromhex(data)
        if msg.length != len(data):
            continue
        for sig, v in msg.decode(data, decode_choices=False).items():
            ref[(n, sig)] = float(v)
    assert len(ref) > 6000 and set(ours) == set(ref)
    bad = [k for k in ref if not math.isclose(ours[k], ref[k], rel_tol=1e-12, abs_tol=1e-9)]
    assert not bad, bad[:5]


# ---------------------------------------------------------------- simdrive (Prius)

def test_simdrive_log_replay(tmp_path):
    run([BIN / "simdrive", "--out", tmp_path / "d", "--duration", "20", "--no-lidar", "--quiet", "--seed", "3"])
    drive = tmp_path / "d" / "drive.lcm"
    out = tmp_path / "can.lcm"
    run([BIN / "can", "--replay", drive, "--out", out])       # default vehicle: the Prius
    fr = [f for f in frames(drive) if f.id != 0x3BC]          # GEAR_PACKET gives no record
    vs = speeds(out)
    assert len(vs) == len(fr) > 1000                          # every other frame is 0x0AA or 0x0B4
    import cantools
    db = cantools.database.load_file(str(DBC_DIR / "toyota_prius_2017_pt_generated.dbc"), strict=False)
    for f, m in zip(fr, vs):
        assert m.utime == f.utime
        d = db.decode_message(f.id, bytes(f.data))
        if f.id == 0x0AA:
            assert m.source == "WHEEL_SPEEDS"
            want = [d["WHEEL_SPEED_FL"], d["WHEEL_SPEED_FR"], d["WHEEL_SPEED_RL"], d["WHEEL_SPEED_RR"]]
            assert np.allclose(np.array(m.wheel_speed_mps) * KMH, want, atol=1e-9)
        else:
            assert m.source == "SPEED" and abs(m.speed_mps * KMH - d["SPEED"]) < 1e-9
    # and against the simulator's truth: the SPEED signal is |v| rounded to 0.01 km/h
    gt = [(t, portobello.pose_t.decode(d)) for _, t, d in read_log(drive, {"GROUND_TRUTH"})]
    gt_t = np.array([t for t, _ in gt])
    gt_v = np.array([np.linalg.norm(p.velocity) for _, p in gt])
    sp = [m for m in vs if m.source == "SPEED"]
    v_at = np.interp([m.utime for m in sp], gt_t, gt_v)
    assert np.abs(np.array([m.speed_mps for m in sp]) - v_at).max() < 0.05
    counters, _ = last_status(out)
    assert counters.get("bad_checksum", 0) == 0 and counters["speed"] == len(vs)
    assert counters["decoded"] == len(frames(drive)) - len(fr) >= 20    # GEAR_PACKET at 1 Hz


def test_simdrive_reversing_signs_the_speed_by_the_gear(tmp_path):
    """simdrive --reverse: the car backs 20 m at its first stop; its speeds are magnitudes
    and GEAR_PACKET says R. VEHICLE_SPEED is the signed forward speed of the truth."""
    run([BIN / "simdrive", "--out", tmp_path / "d", "--duration", "45", "--no-lidar", "--quiet", "--seed", "5",
         "--reverse", "20"])
    drive = tmp_path / "d" / "drive.lcm"
    out = tmp_path / "can.lcm"
    run([BIN / "can", "--replay", drive, "--out", out])
    vs = [m for m in speeds(out) if m.source == "SPEED"]
    gt = [(t, portobello.pose_t.decode(d)) for _, t, d in read_log(drive, {"GROUND_TRUTH"})]
    gt_t = np.array([t for t, _ in gt])
    yaw = np.array([math.atan2(2 * (p.orientation[0] * p.orientation[3] + p.orientation[1] * p.orientation[2]),
                               1 - 2 * (p.orientation[2] ** 2 + p.orientation[3] ** 2)) for _, p in gt])
    fwd = np.array([p.velocity[0] for _, p in gt]) * np.cos(yaw) + np.array([p.velocity[1] for _, p in gt]) * np.sin(yaw)
    v_at = np.interp([m.utime for m in vs], gt_t, fwd)
    v = np.array([m.speed_mps for m in vs])
    assert v.min() < -2.4 and np.sum(v < -0.1) > 100                        # backing at 2.5 m/s
    # the gear changes at rest, so the sign is right on every record
    assert np.abs(v - v_at).max() < 0.05, np.abs(v - v_at).max()
    # backed about 20 m and drove forward again
    back = -np.sum(np.minimum(fwd, 0)) * 0.01
    assert 19.5 < back < 20.5, back


# ---------------------------------------------------------------- bad input

GOOD_WS = "0AA#25B525B525A0258D"
GOOD_SPEED = "0B4#000000001D0B7A5E"


def test_bad_input_is_counted_never_fatal(tmp_path):
    src = tmp_path / "bad.log"
    t = 1533226488.0
    lines = [
        f"({t + 0.001:.6f}) can0 {GOOD_WS}",
        f"({t + 0.002:.6f}) can0 {GOOD_SPEED}",
        f"({t + 0.003:.6f}) can0 0B4#000000001D0B7A5F",     # wrong checksum
        f"({t + 0.004:.6f}) can0 0B4#000000001D0B7A",       # wrong DLC (7)
        f"({t + 0.005:.6f}) can0 0AA#25B525B525A025",       # wrong DLC (7)
        f"({t + 0.006:.6f}) can0 7FF#0102",                 # unknown id
        f"({t + 0.007:.6f}) can0 20000004#0000000000000000",  # error frame (controller)
        f"({t + 0.008:.6f}) can0 0B4#R",                    # remote frame
        f"({t + 0.009:.6f}) can0 0AA#25B525B525A0258Z",     # garbled hex
        "(1533226488.01) can0",                             # truncated line
        "garbage \x01\x02 line",
        f"({t + 0.010:.6f}) can1 {GOOD_WS}",                # other bus
        f"({t + 0.0005:.6f}) can0 {GOOD_WS}",               # time backwards: still decoded
        f"({t + 0.011:.6f}) can0 {GOOD_SPEED}",
        f"({t + 0.012:.6f}) can0 0AA#25B525B5",             # truncated at the end of the file
    ]
    src.write_bytes(("\n".join(lines)).encode("latin-1"))
    out = tmp_path / "out.lcm"
    p = run([BIN / "can", "--candump", src, "--out", out, "--vehicle", RAV4])
    counters, st = last_status(out)
    assert counters["frames"] == 12
    assert counters["bad_checksum"] == 1
    assert counters["bad_length"] == 3
    assert counters["unknown_id"] == 1
    assert counters["error_frame"] == 1
    assert counters["remote_frame"] == 1
    assert counters["line_bad_data"] == 1 and counters["line_bad_id"] == 1 and counters["line_bad_time"] == 1
    assert counters["other_bus"] == 1
    assert counters["time_backwards"] == 1
    assert counters["speed"] == 4
    assert len(frames(out)) == 12 and len(speeds(out, event_time_is_utime=False)) == 4
    assert f"{src}:3: id 0x0B4: checksum" in p.stderr
    assert f"{src}:9:" in p.stderr                       # file:line:col of the garbled line
    ts = [t for _, t, _ in read_log(out)]
    assert ts == sorted(ts)                               # the late frame is logged at the newest time


def test_replay_bad_events_counted(tmp_path):
    import lcm
    src = tmp_path / "in.lcm"
    log = lcm.EventLog(str(src), "w", overwrite=True)
    t0 = 1_700_000_000_000_000

    def frame(t, fid, data, **kw):
        f = portobello.can_frame_t()
        f.utime, f.bus, f.id, f.len, f.data = t, 0, fid, len(data), list(data)
        for k, v in kw.items():
            setattr(f, k, v)
        return f.encode()

    log.write_event(t0, "CAN_FRAME", frame(t0, 0x0AA, bytes.fromhex("25B525B525A0258D")))
    log.write_event(t0 + 1000, "CAN_FRAME", b"\x00" * 5)                      # does not decode
    bad = portobello.can_frame_t()
    bad.utime, bad.id, bad.len, bad.data = t0 + 2000, 0x0AA, 9, list(range(9))  # 9 bytes classic
    log.write_event(t0 + 2000, "CAN_FRAME", bad.encode())
    log.write_event(t0 + 3000, "CAN_FRAME", frame(t0 + 3000, 0x900, b"\x00"))  # 11-bit id > 0x7FF
    log.write_event(t0 + 4000, "CAN_FRAME", frame(t0 + 4000, 0x0B4, bytes.fromhex("000000001D0B7A5E")))
    log.close()
    out = tmp_path / "out.lcm"
    run([BIN / "can", "--replay", src, "--out", out])
    counters, _ = last_status(out)
    assert counters["undecodable"] == 1 and counters["bad_frame"] == 2
    assert counters["speed"] == 2 and len(speeds(out)) == 2


def test_bad_dbc_and_options(tmp_path):
    dbc = tmp_path / "toyota_broken.dbc"
    dbc.write_text('BO_ 180 SPEED: 8 XXX\n SG_ SPEED : 47|16@0+ (0.01,0) [0|250] "km/h" XXX\n'
                   ' SG_ CHECKSUM : 63|8@0+ (1,0 [0|255] "" XXX\n')
    p = run([BIN / "can", "--candump", SAMPLE, "--out", tmp_path / "o.lcm", "--dbc", dbc], check=False)
    assert p.returncode == 1 and f"{dbc}:3:30: ')' expected after the offset" in p.stderr
    p = run([BIN / "can", "--help"])
    assert "--candump" in p.stdout and "listen-only" in p.stdout
    assert run([BIN / "can", "--replay", SAMPLE], check=False).returncode == 2           # no --out
    assert run([BIN / "can", "--replay", "x", "--candump", "y", "--out", "z"], check=False).returncode == 2
    p = run([BIN / "can", "--candump", SAMPLE, "--out", tmp_path / "o.lcm", "--bus", "x"], check=False)
    assert p.returncode == 2 and "--bus" in p.stderr
    p = run([BIN / "can", "--candump", tmp_path / "missing.log", "--out", tmp_path / "o.lcm"], check=False)
    assert p.returncode == 1 and "missing.log" in p.stderr


@pytest.mark.live
def test_live_bus_from_stdin():
    """`candump -L can0 | can --candump - --realtime` in miniature: the sample on stdin,
    published on the live bus (real UDP multicast, private port, ttl=0) at its own pace
    and counted by log-summary listening on the bus. (lcm-logger is not used: LCM's
    default 30-deep subscription queue drops bursts; pb_bus subscribes 1000 deep.)"""
    import subprocess
    import time
    url = "udpm://239.255.76.67:7791?ttl=0&recv_buf_size=8388608"
    listener = subprocess.Popen([str(BIN / "log-summary"), "--lcm-url", url],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(0.5)  # let it subscribe
        with open(SAMPLE, "rb") as f:
            p = run([BIN / "can", "--candump", "-", "--realtime", "--lcm-url", url, "--vehicle", RAV4],
                    stdin=f, timeout=60)
        time.sleep(0.5)
        out, err = interrupt(listener)
    finally:
        if listener.poll() is None:
            listener.kill()
    assert "4516 frames, 249 VEHICLE_SPEED" in p.stderr
    counts = {l.split()[0]: l.split() for l in out.splitlines() if l.split()}
    assert int(counts["CAN_FRAME"][1]) == 4516 and int(counts["VEHICLE_SPEED"][1]) == 249
    assert float(counts["CAN_FRAME"][4]) == pytest.approx(2.0, abs=0.01)      # the capture's span
    assert int(counts["STATUS"][1]) >= 1
    assert "can: 4516 frames" in out                                        # its CAN section


def test_socketcan_unavailable_is_a_clear_error():
    """This kernel has no AF_CAN (a machine with it but no vcan_pb9 says so instead)."""
    p = run([BIN / "can", "--iface", "vcan_pb9", "--lcm-url", "udpm://239.255.76.67:7790?ttl=0"], check=False, timeout=20)
    assert p.returncode == 1
    assert "vcan_pb9" in p.stderr and ("AF_CAN" in p.stderr or "no such CAN interface" in p.stderr)


# ---------------------------------------------------------------- real data (make test-real)

@pytest.mark.real
def test_real_rav4_full_segment(tmp_path):
    src = SHARED_DATA / "can_rav4_comma2k19"
    if not src.exists():
        pytest.skip("../shared/data/can_rav4_comma2k19 absent")
    out = tmp_path / "rav4.lcm"
    run([BIN / "can", "--candump", src / "rav4_2018-08-02_seg40.candump.log", "--out", out, "--vehicle", RAV4])
    assert len(frames(out)) == 135468
    vs = speeds(out)
    err, n = check_against_comma(vs, src / "can_speed_wheelspeeds_mps.csv")
    assert n == 4974
    ts = [t for _, t, _ in read_log(out)]
    assert ts == sorted(ts)
    counters, _ = last_status(out)
    assert counters.get("bad_checksum", 0) == 0 and counters.get("time_backwards", 0) == 0
