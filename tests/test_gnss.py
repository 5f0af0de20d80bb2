"""gnss: real u-blox captures (tests/data/ublox, with their oracle) -> GNSS_FIX.

Checks message and error counts against the oracle, every NAV-PVT fix field against
the oracle CSV and against pyubx2 (a maintained decoder), NMEA fixes against
pynmeagps, resynchronisation after garbage, determinism, and the live path through a
real pseudo-terminal serial device onto the bus.
"""
import calendar
import csv
import json
import math
import os
import random
import subprocess
import time

import pytest

from conftest import BIN, ROOT, SHARED_DATA, interrupt, read_log, run

import portobello

DATA = ROOT / "tests" / "data" / "ublox"
ORACLE = DATA / "oracle"
GNSS = BIN / "gnss"
UBX_LOGS = ["pygpsdata-MIXED.log", "pygpsdata-MIXED3.log", "pygpsdata-MIXED3BADCK.log",
            "pygpsdata-NAV.log", "pygpsdata-BADCK2.log", "pygpsdata-ESF.log",
            "pygpsdata-HNR.log", "pygpsdata-SF-calibration.log"]
NMEA_LOG = "ublox-zed-f9p-nmea.stripped.nmea"
LIVE_URL = "udpm://239.255.76.67:7810?ttl=0&recv_buf_size=8388608"


def convert(src, out, *extra):
    p = run([GNSS, "--file", src, "--out", out, *extra], check=False, timeout=60)
    assert p.returncode == 0, p.stderr
    fixes, statuses = [], []
    for ch, ts, data in read_log(out):
        if ch == "GNSS_FIX":
            m = portobello.gnss_fix_t.decode(data)
            assert ts == m.utime            # event time is the fix's receiver time
            fixes.append(m)
        elif ch == "STATUS":
            statuses.append(portobello.status_t.decode(data))
    assert statuses, "no STATUS written"
    counters = dict(zip(statuses[-1].counter_names, statuses[-1].counter_values))
    return fixes, counters, statuses[-1], p.stderr


def pvt_rows(name):
    path = ORACLE / f"{name}.navpvt.csv"
    if not path.exists():
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


def pvt_utime(r):
    """UTC date/time + nano (ns, signed), rounded to the nearest microsecond."""
    s = calendar.timegm((int(r["year"]), int(r["month"]), int(r["day"]),
                         int(r["hour"]), int(r["min"]), int(r["sec"])))
    return s * 1_000_000 + math.floor((int(r["nano"]) + 500) / 1000)


@pytest.mark.parametrize("name", UBX_LOGS)
def test_counts_and_errors_match_oracle(tmp_path, name):
    summary = json.loads((ORACLE / f"{name}.summary.json").read_text())
    fixes, c, st, err = convert(DATA / name, tmp_path / "o.lcm")
    assert c["ubx_frames"] == summary["ubx_messages_valid_checksum"]
    assert c["ubx_nav_pvt"] == summary["nav_pvt_count"]
    assert c["fixes_ubx"] == summary["nav_pvt_count"]
    bad = summary["bad_checksum_candidates_at"]
    assert c["ubx_bad_checksum"] == len(bad)
    # every counted error names its byte offset
    for off in bad:
        assert f"byte {off}: ubx_bad_checksum" in err
    if bad:
        assert "ubx_bad_checksum" in st.last_error
    for k in ("ubx_too_long", "nmea_bad_checksum", "nmea_bad_field", "nav_pvt_bad_length"):
        assert c[k] == 0, k
    nmea = ORACLE / f"{name}.nmea_summary.json"
    if nmea.exists():
        assert c["nmea_sentences"] == json.loads(nmea.read_text())["nmea_valid"]
        assert c["nmea_gga"] == json.loads(nmea.read_text())["counts"].get("GPGGA", 0)


@pytest.mark.parametrize("name", [n for n in UBX_LOGS if pvt_rows(n)])
def test_every_nav_pvt_matches_oracle(tmp_path, name):
    rows = pvt_rows(name)
    fixes, c, _, _ = convert(DATA / name, tmp_path / "o.lcm")
    ubx = [f for f in fixes if not math.isnan(f.heading_acc_deg)]   # NaN in NMEA fixes only
    assert len(ubx) == len(rows) > 0
    for f, r in zip(ubx, rows):
        assert f.utime == pvt_utime(r)
        assert f.lat_deg == pytest.approx(int(r["lat"]) * 1e-7, abs=1e-12)
        assert f.lon_deg == pytest.approx(int(r["lon"]) * 1e-7, abs=1e-12)
        assert f.lat_deg == pytest.approx(float(r["lat_deg"]), abs=1e-12)
        assert f.alt_m == pytest.approx(int(r["height"]) / 1000, abs=1e-9)
        assert f.alt_msl_m == pytest.approx(int(r["hMSL"]) / 1000, abs=1e-9)
        assert f.h_acc_m == pytest.approx(int(r["hAcc"]) / 1000, abs=1e-9)
        assert f.v_acc_m == pytest.approx(int(r["vAcc"]) / 1000, abs=1e-9)
        assert list(f.vel_ned_mps) == pytest.approx(
            [int(r["velN"]) / 1000, int(r["velE"]) / 1000, int(r["velD"]) / 1000], abs=1e-9)
        assert f.speed_mps == pytest.approx(int(r["gSpeed"]) / 1000, abs=1e-9)
        assert f.heading_deg == pytest.approx(int(r["headMot"]) * 1e-5 % 360, abs=1e-9)
        assert f.heading_acc_deg == pytest.approx(int(r["headAcc"]) * 1e-5, abs=1e-9)
        assert f.num_sv == int(r["numSV"])
        assert int(r["flags"]) & 1   # gnssFixOK in every oracle row, so fix type = fixType
        assert f.fix_type == int(r["fixType"])


@pytest.mark.parametrize("name", ["pygpsdata-MIXED.log", "pygpsdata-NAV.log", "pygpsdata-MIXED3.log"])
def test_nav_pvt_matches_pyubx2(tmp_path, name):
    """Second, independent decoder: pyubx2 (PyPI) on the same bytes."""
    import pyubx2  # the independent oracle: in tools/requirements.txt, checked by deps.sh --check
    with open(DATA / name, "rb") as f:
        msgs = [p for _, p in pyubx2.UBXReader(f, protfilter=pyubx2.UBX_PROTOCOL, quitonerror=0)
                if p is not None and p.identity == "NAV-PVT"]
    fixes, _, _, _ = convert(DATA / name, tmp_path / "o.lcm")
    assert len(fixes) == len(msgs) > 0
    for f, m in zip(fixes, msgs):
        assert f.lat_deg == pytest.approx(m.lat, abs=1e-12)
        assert f.lon_deg == pytest.approx(m.lon, abs=1e-12)
        assert f.alt_m == pytest.approx(m.height / 1000, abs=1e-9)
        assert f.alt_msl_m == pytest.approx(m.hMSL / 1000, abs=1e-9)
        assert f.fix_type == m.fixType and f.num_sv == m.numSV


def test_nmea_log_fixes_match_pynmeagps(tmp_path):
    """A pure-NMEA ZED-F9P log: one fix per epoch (GGA + RMC + GST merged), every value
    against pynmeagps's decode of the same sentences."""
    import pynmeagps
    summary = json.loads((ORACLE / f"{NMEA_LOG}.nmea_summary.json").read_text())
    fixes, c, _, _ = convert(DATA / NMEA_LOG, tmp_path / "o.lcm")
    assert c["nmea_sentences"] == summary["nmea_valid"] == 1015
    assert c["nmea_gga"] == summary["counts"]["GNGGA"] and c["nmea_rmc"] == summary["counts"]["GNRMC"]
    assert c["nmea_bad_checksum"] == summary["bad_checksum"] == 0
    assert c["skipped_bytes"] == 0
    ggas, rmcs, gsts = [], [], []
    with open(DATA / NMEA_LOG, "rb") as f:
        for _, m in pynmeagps.NMEAReader(f, quitonerror=0):
            if m is not None and m.msgID == "GGA":
                ggas.append(m)
            elif m is not None and m.msgID == "RMC":
                rmcs.append(m)
            elif m is not None and m.msgID == "GST":
                gsts.append(m)
    assert c["nmea_gst"] == len(gsts) == 29
    assert len(fixes) == len(ggas) == len(rmcs) == 29
    for i, (f, g, r, e) in enumerate(zip(fixes, ggas, rmcs, gsts)):
        assert g.time == r.time
        day = calendar.timegm((r.date.year, r.date.month, r.date.day, 0, 0, 0))
        t = g.time
        assert f.utime == (day + t.hour * 3600 + t.minute * 60 + t.second) * 1_000_000 + t.microsecond
        assert f.lat_deg == pytest.approx(g.lat, abs=1e-9)
        assert f.lon_deg == pytest.approx(g.lon, abs=1e-9)
        assert f.alt_msl_m == pytest.approx(g.alt, abs=1e-9)
        assert f.alt_m == pytest.approx(g.alt + g.sep, abs=1e-9)
        assert f.num_sv == g.numSV
        assert f.fix_type == portobello.gnss_fix_t.FIX_3D and g.quality == 1
        assert f.speed_mps == pytest.approx(r.spd * 1852 / 3600, abs=1e-9)
        assert e.time == g.time
        if i == 0:   # GST comes last in the epoch: known to be sent only after the first one
            assert math.isnan(f.h_acc_m) and math.isnan(f.v_acc_m)
        else:        # horizontal RMS from GST's per-axis sigmas
            assert f.h_acc_m == pytest.approx(math.hypot(e.stdLat, e.stdLong), abs=1e-12)
            assert f.v_acc_m == pytest.approx(e.stdAlt, abs=1e-12)
    first = summary["first_GNGGA"]
    assert fixes[0].lat_deg == pytest.approx(-45.8775671667, abs=1e-9)
    assert fixes[0].lon_deg == pytest.approx(170.5001113333, abs=1e-9)
    assert "003956.00" in first["sentence"]


def test_nmea_fills_an_epoch_whose_nav_pvt_was_lost(tmp_path):
    """MIXED3BADCK: NAV-PVT then GGA each second; the 08:02:48 NAV-PVT fails its checksum,
    so that epoch's GGA is published (fill); the 08:02:47 GGA is a duplicate (suppressed)."""
    fixes, c, _, _ = convert(DATA / "pygpsdata-MIXED3BADCK.log", tmp_path / "o.lcm")
    assert (c["fixes_ubx"], c["fixes_nmea"], c["nmea_fills"], c["nmea_suppressed"]) == (1, 1, 1, 1)
    t0 = calendar.timegm((2022, 1, 18, 8, 2, 47))
    assert [f.utime for f in fixes] == [t0 * 1_000_000 - 175, (t0 + 1) * 1_000_000]
    g = fixes[1]   # $GPGGA,080248.00,5327.04312,N,00214.41389,W,1,07,1.63,36.8,M,48.5,M,,*78
    assert g.lat_deg == pytest.approx(53 + 27.04312 / 60, abs=1e-12)
    assert g.lon_deg == pytest.approx(-(2 + 14.41389 / 60), abs=1e-12)
    assert g.alt_msl_m == pytest.approx(36.8) and g.alt_m == pytest.approx(36.8 + 48.5)
    assert g.num_sv == 7 and g.fix_type == portobello.gnss_fix_t.FIX_3D


def test_nmea_suppressed_while_nav_pvt_arrives(tmp_path):
    fixes, c, _, _ = convert(DATA / "pygpsdata-MIXED3.log", tmp_path / "o.lcm")
    assert (c["fixes_ubx"], c["fixes_nmea"], c["nmea_suppressed"]) == (3, 0, 2)
    # Without the NAV-PVTs the same GGAs become fixes, but with no date anywhere (no RMC,
    # no NAV-PVT) they have no UTC time: counted and not written to the log.
    text = (DATA / "pygpsdata-MIXED3.log").read_bytes().decode("latin-1")
    lines = [l[l.index("$GP"):] + "\n" for l in text.split("\n") if "$GP" in l]
    assert len(lines) == 4
    (tmp_path / "n.nmea").write_text("".join(lines), encoding="latin-1")
    fixes, c, _, err = convert(tmp_path / "n.nmea", tmp_path / "n.lcm")
    assert (c["nmea_gga"], c["fixes_nmea"], c["nmea_no_date"], c["fix_no_utc_dropped"]) == (2, 2, 2, 2)
    assert fixes == [] and "without a UTC date" in err


def test_garbage_length_never_swallows_good_frames(tmp_path):
    """A fake UBX header claiming a long payload (and garbage, and a lone '$') in front
    of every real frame: every NAV-PVT is still decoded, the fakes are counted."""
    data = (DATA / "pygpsdata-MIXED.log").read_bytes()
    rows = pvt_rows("pygpsdata-MIXED.log")
    offsets = [int(r["offset"]) for r in rows]
    out, last = bytearray(), 0
    for off in offsets:
        out += data[last:off]
        out += b"\xb5\x62\x01\x07\x00\x10" + b"$GPG\x00" + bytes(range(7))  # claims 4096 bytes
        last = off
    out += data[last:]
    (tmp_path / "g.ubx").write_bytes(out)
    fixes, c, _, err = convert(tmp_path / "g.ubx", tmp_path / "o.lcm")
    assert c["fixes_ubx"] == len(rows) == 39
    assert [f.lat_deg for f in fixes] == pytest.approx([int(r["lat"]) * 1e-7 for r in rows], abs=1e-12)
    assert c["ubx_frames"] == 300
    assert c["ubx_bad_checksum"] + c["ubx_too_long"] + c["ubx_truncated"] == 39
    assert c["skipped_bytes"] > 0


def test_fuzzed_copies_never_crash_nor_invent_fixes(tmp_path):
    """Random byte flips, insertions and a cut: exit 0, errors counted, every fix written
    is one of the real NAV-PVTs (no corrupted value gets through)."""
    data = (DATA / "pygpsdata-MIXED.log").read_bytes()
    good = {(int(r["lat"]), int(r["lon"]), int(r["height"])) for r in pvt_rows("pygpsdata-MIXED.log")}
    rng = random.Random(5)
    for k in range(6):
        b = bytearray(data)
        for _ in range(40):
            i = rng.randrange(len(b))
            if rng.random() < 0.5:
                b[i] = rng.randrange(256)
            else:
                b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        b = b[: rng.randrange(len(b) // 2, len(b))]
        (tmp_path / "f.ubx").write_bytes(b)
        fixes, c, _, _ = convert(tmp_path / "f.ubx", tmp_path / "o.lcm")
        errors = sum(v for n, v in c.items() if n.startswith(("ubx_bad", "ubx_too", "ubx_trunc")))
        assert errors > 0
        assert 0 < c["fixes_ubx"] <= 39
        for f in fixes:
            key = (round(f.lat_deg * 1e7), round(f.lon_deg * 1e7), round(f.alt_m * 1000))
            assert key in good


def test_truncated_frame_at_end_is_counted(tmp_path):
    data = (DATA / "pygpsdata-NAV.log").read_bytes()
    (tmp_path / "t.ubx").write_bytes(data[:50])     # half of the first NAV-PVT
    fixes, c, st, err = convert(tmp_path / "t.ubx", tmp_path / "o.lcm")
    # This NAV-PVT's iTOW bytes happen to hold B5 62 at byte 7: after the cut frame is
    # reported, scanning resumes at byte 1 and that candidate is cut short too.
    assert data[7:9] == b"\xb5\x62"
    assert fixes == [] and c["ubx_truncated"] == 2 and c["ubx_frames"] == 0
    assert "byte 0: ubx_truncated" in err and "50 of 100 bytes" in err
    assert "byte 7: ubx_truncated" in err


def test_output_is_deterministic(tmp_path):
    for name in ("pygpsdata-MIXED.log", NMEA_LOG, "pygpsdata-BADCK2.log"):
        convert(DATA / name, tmp_path / "a.lcm")
        convert(DATA / name, tmp_path / "b.lcm")
        assert (tmp_path / "a.lcm").read_bytes() == (tmp_path / "b.lcm").read_bytes()


def test_status_heartbeat_on_fix_time(tmp_path):
    fixes, c, last, _ = convert(DATA / "pygpsdata-MIXED.log", tmp_path / "o.lcm")
    beats = [portobello.status_t.decode(d) for ch, _, d in read_log(tmp_path / "o.lcm") if ch == "STATUS"]
    span_s = (fixes[-1].utime - fixes[0].utime) / 1e6
    assert len(beats) >= span_s  # one per second of receiver time, plus the final one
    assert last.state == portobello.status_t.STATE_STOPPING and last.module == "gnss" and last.pid == 0


def test_command_line(tmp_path):
    assert "usage: gnss" in run([GNSS, "--help"]).stdout
    p = run([GNSS, "--file", tmp_path / "missing", "--out", tmp_path / "o.lcm"], check=False)
    assert p.returncode == 1 and "missing: No such file" in p.stderr
    p = run([GNSS, "--file", DATA / NMEA_LOG, "--device", "/dev/null"], check=False)
    assert p.returncode == 2
    p = run([GNSS, "--device", "/dev/null", "--baud", "12345"], check=False)
    assert p.returncode == 2 and "--baud" in p.stderr
    p = run([GNSS, "--device", "/dev/null"], check=False)
    assert p.returncode == 1 and "not a serial device" in p.stderr
    p = run([GNSS, "--file", DATA / NMEA_LOG, "--out", tmp_path / "o.lcm", "--nmea-holdoff", "x"], check=False)
    assert p.returncode == 2


@pytest.mark.live
def test_live_serial_pty_to_bus():
    """A real serial device path (pseudo-terminal): Python writes a capture into the
    master side in small chunks; gnss reads the raw tty and publishes on the bus."""
    import lcm
    import tty
    master, slave = os.openpty()   # a machine without /dev/pts fails here: the driver needs a tty
    tty.setraw(master)
    path = os.ttyname(slave)
    lc = lcm.LCM(LIVE_URL)
    got, status = [], []
    lc.subscribe("GNSS_FIX", lambda ch, d: got.append(portobello.gnss_fix_t.decode(d)))
    lc.subscribe("STATUS", lambda ch, d: status.append(portobello.status_t.decode(d)))
    proc = subprocess.Popen([str(GNSS), "--device", path, "--baud", "115200", "--lcm-url", LIVE_URL,
                             "--status-period", "0.2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 10
        while not status and time.time() < deadline:   # running (and the tty opened) once STATUS comes
            lc.handle_timeout(100)
        assert status, "no STATUS from gnss"
        data = (DATA / "pygpsdata-MIXED.log").read_bytes() + (DATA / "pygpsdata-MIXED3BADCK.log").read_bytes()
        for i in range(0, len(data), 997):
            os.write(master, data[i:i + 997])
            lc.handle_timeout(5)
        deadline = time.time() + 10
        while len(got) < 40 and time.time() < deadline:   # the 41st (an NMEA fill) comes at the stop
            lc.handle_timeout(100)
        time.sleep(0.3)
        _, err = interrupt(proc)
        for _ in range(20):
            lc.handle_timeout(50)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
        os.close(slave)
    assert proc.returncode == 0, err
    rows = pvt_rows("pygpsdata-MIXED.log") + pvt_rows("pygpsdata-MIXED3BADCK.log")
    ubx = [f for f in got if not math.isnan(f.heading_acc_deg)]   # NaN in NMEA fixes only
    assert len(ubx) == 40 and len(got) == 41
    assert got[-1].utime == calendar.timegm((2022, 1, 18, 8, 2, 48)) * 1_000_000   # GGA of the lost NAV-PVT
    assert [f.utime for f in ubx] == [pvt_utime(r) for r in rows]
    assert [f.lat_deg for f in ubx] == pytest.approx([int(r["lat"]) * 1e-7 for r in rows], abs=1e-12)
    c = dict(zip(status[-1].counter_names, status[-1].counter_values))
    assert c["ubx_bad_checksum"] == 1 and c["ubx_nav_pvt"] == 40 and c["nmea_fills"] == 1
    assert status[-1].state == portobello.status_t.STATE_STOPPING and status[-1].pid == proc.pid


@pytest.mark.real
def test_real_gpsd_log_with_header_and_chk_oracle(tmp_path):
    """The original gpsd regression log ('#' header lines, then receiver bytes) and
    gpsd's own decoded output (.chk TPV) as a second oracle for the NMEA fixes."""
    src = SHARED_DATA / "ublox" / "gpsd" / "ublox-zed-f9p-nmea.log"
    chk = SHARED_DATA / "ublox" / "gpsd" / "ublox-zed-f9p-nmea.log.chk"
    if not src.exists():
        pytest.skip(f"{src} absent")
    fixes, c, _, _ = convert(src, tmp_path / "o.lcm")
    assert c["nmea_sentences"] == 1015 and c["fixes_nmea"] == 29 and c["skipped_bytes"] > 0
    tpv = {}
    for line in chk.read_text().splitlines():
        if '"class":"TPV"' in line:
            j = json.loads(line)
            if "lat" in j and "time" in j:
                tpv.setdefault(j["time"], j)
    matched = 0
    for f in fixes:
        t = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(f.utime // 1_000_000))
        j = next((v for k, v in tpv.items() if k.startswith(t)), None)
        if j is None:
            continue
        matched += 1
        assert f.lat_deg == pytest.approx(j["lat"], abs=1e-8)
        assert f.lon_deg == pytest.approx(j["lon"], abs=1e-8)
    assert matched >= 25
