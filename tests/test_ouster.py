"""modules/ouster: Ouster UDP lidar/IMU packets -> LIDAR_SCAN and IMU.

Fast tests run on the captures committed in tests/data/ouster (OS1-64 LEGACY full frame,
OS2-32 LEGACY and OS2-128 RNG19 trimmed, the shot-limiting packet, seven OS1-64 metadata
files) against the reference values in tests/data/ouster/oracle (ouster-sdk 1.0.1 and an
independent decoder), and on packets this file builds from the documented layouts (the
DUAL and RNG15 profiles, of which no capture is available), damaged captures, IPv4
fragments and a live loopback replay. `real` tests check the full OS2-32 and OS2-128
frames in ../shared/data."""
import csv
import hashlib
import json
import random
import socket
import struct
import subprocess
import threading
import time

import numpy as np
import pytest

import portobello
from conftest import BIN, ROOT, SHARED_DATA, read_log, run

DATA = ROOT / "tests" / "data" / "ouster"
ORACLE = DATA / "oracle"
OS1 = DATA / "OS-1-64_1024x10_fw20.pcap"
OS1_META = DATA / "OS-1-64_sensor_config_reduced.json"
OS2_32 = DATA / "OS-2-32-U0_v2.0.0_1024x10_first17.pcap"
OS2_32_META = DATA / "OS-2-32-U0_v2.0.0_1024x10.json"
OS2_128 = DATA / "OS-2-128-U1_v2.3.0_1024x10_first8.pcap"
OS2_128_META = DATA / "OS-2-128-U1_v2.3.0_1024x10.json"
SHOT = DATA / "shot_limiting_test.pcap"
SHOT_META = DATA / "shot_limiting_test.json"
REAL = SHARED_DATA / "ouster_pcaps"
LCM_URL = "udpm://239.255.76.67:7800?ttl=0&recv_buf_size=8388608"


# ---------------------------------------------------------------- helpers

def pcap_records(path):
    """(sec, usec, frame bytes) of every record of a little-endian us pcap."""
    d = path.read_bytes()
    assert struct.unpack_from("<I", d, 0)[0] == 0xA1B2C3D4
    off, out = 24, []
    while off < len(d):
        sec, usec, incl, _ = struct.unpack_from("<IIII", d, off)
        out.append((sec, usec, d[off + 16:off + 16 + incl]))
        off += 16 + incl
    return out


def udp_of(frame):
    """(dst port, payload) of an Ethernet/IPv4/UDP frame."""
    ihl = (frame[14] & 15) * 4
    u = 14 + ihl
    dport, ulen = struct.unpack_from(">HH", frame, u + 2)
    return dport, frame[u + 8:u + ulen]


def datagrams(path):
    return [(sec, usec) + udp_of(f) for sec, usec, f in pcap_records(path)]


def eth_ipv4(payload_ip, ident, frag_field):
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(payload_ip), ident, frag_field, 64, 17, 0,
                     bytes([127, 0, 0, 1]), bytes([127, 0, 0, 1]))
    return b"\0" * 12 + b"\x08\x00" + ip + payload_ip


def udp_bytes(dport, payload):
    return struct.pack(">HHHH", 40000, dport, 8 + len(payload), 0) + payload


def write_pcap(path, records):
    """records: (sec, usec, frame bytes)."""
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 1))
    for sec, usec, frame in records:
        out += struct.pack("<IIII", sec, usec, len(frame), len(frame)) + frame
    path.write_bytes(bytes(out))


def write_udp_pcap(path, dgrams):
    """dgrams: (sec, usec, dst port, payload); one unfragmented IPv4 datagram each."""
    write_pcap(path, [(s, u, eth_ipv4(udp_bytes(p, pl), i & 0xFFFF, 0x4000))
                      for i, (s, u, p, pl) in enumerate(dgrams)])


def ouster(tmp_path, pcap, meta, *extra, name="out.lcm", check=True):
    out = tmp_path / name
    p = run([BIN / "ouster", "--pcap", pcap, "--metadata", meta, "--out", out, *extra], check=check)
    return p, out


def decode(out):
    scans, imus, status = [], [], []
    for ch, ts, data in read_log(out):
        if ch == "LIDAR_SCAN":
            scans.append((ts, portobello.lidar_scan_t.decode(data), len(data)))
        elif ch == "IMU":
            imus.append((ts, portobello.imu_t.decode(data)))
        elif ch == "STATUS":
            status.append(portobello.status_t.decode(data))
    return scans, imus, status


def counters(st):
    return dict(zip(st.counter_names, st.counter_values))


def image(scan, field, dtype):
    v = getattr(scan, field)
    a = np.frombuffer(v, np.uint8) if isinstance(v, (bytes, bytearray)) else np.asarray(v)
    return a.astype(dtype).reshape(scan.rows, scan.cols)


def md5(a):
    return hashlib.md5(np.ascontiguousarray(a).tobytes()).hexdigest()


def oracle_summary(name):
    return json.loads((ORACLE / f"{name}_oracle_summary.json").read_text())


def oracle_pixels(name):
    with open(ORACLE / f"{name}_oracle_pixels.csv") as f:
        return list(csv.DictReader(f))


def points(log):
    """{(row, col): (x, y, z)} from ouster-points (common/pb_scan)."""
    p = run([BIN / "ouster-points", "--in", log])
    pts = {}
    for line in p.stdout.splitlines()[1:]:
        f = line.split(",")
        pts[(int(f[2]), int(f[3]))] = (float(f[4]), float(f[5]), float(f[6]))
    return pts


def check_oracle_pixels(scan, log, name, cols=None, signal=True):
    """Every oracle pixel (of the given measurement ids): range, signal, reflectivity,
    near-IR exactly; xyz through pb_scan within 1 mm. Returns the number checked."""
    rng = image(scan, "range_mm", np.uint32)
    refl = image(scan, "reflectivity", np.uint8)
    if signal:
        sig = image(scan, "signal", np.uint16)
        nir = image(scan, "near_ir", np.uint16)
    pts = points(log)
    n = worst = 0
    for row in oracle_pixels(name):
        c, r = int(row["measurement_id"]), int(row["row"])
        if cols is not None and c not in cols:
            continue
        assert int(row["frame_id"]) == scan.seq
        assert rng[r, c] == int(row["range_mm"]), (r, c)
        assert refl[r, c] == int(row["reflectivity"]), (r, c)
        if signal:
            assert sig[r, c] == int(row["signal"]) and nir[r, c] == int(row["near_ir"]), (r, c)
        if int(row["range_mm"]) == 0:
            assert (r, c) not in pts
        else:
            ref = np.array([float(row["x_m"]), float(row["y_m"]), float(row["z_m"])])
            err = np.abs(np.array(pts[(r, c)]) - ref).max()
            worst = max(worst, err)
            assert err < 1e-3, ((r, c), pts[(r, c)], ref)
        n += 1
    assert n > 0
    return n, worst


# ---------------------------------------------------------------- real captures vs oracle

def test_help():
    p = run([BIN / "ouster", "--help"])
    assert "--pcap" in p.stdout and "RNG15_RFL8_NIR8" in p.stdout
    p = run([BIN / "ouster", "--pcap", OS1], check=False)
    assert p.returncode == 2 and "--metadata" in p.stderr


def test_os1_64_legacy_frame_matches_oracle(tmp_path):
    p, out = ouster(tmp_path, OS1, OS1_META)
    scans, imus, status = decode(out)
    assert len(scans) == 1
    _, s, size = scans[0]
    summ = oracle_summary("OS-1-64_1024x10_fw20")
    fr = summ["frames"][0]
    assert (s.seq, s.rows, s.cols, s.npixels, s.nsignal) == (fr["frame_id"], 64, 1024, 65536, 65536)
    assert s.sensor == "Ouster"   # the reduced metadata has no prod_line
    f = fr["fields"]
    for field, key, dt in (("range_mm", "RANGE", np.uint32), ("signal", "SIGNAL", np.uint16),
                           ("reflectivity", "REFLECTIVITY", np.uint8), ("near_ir", "NEAR_IR", np.uint16)):
        a = image(s, field, dt)
        assert md5(a) == f[key]["md5_staggered_rowmajor"], field
        assert int(a.astype(np.int64).sum()) == f[key]["sum"] and int(np.count_nonzero(a)) == f[key]["nonzero"]
    # per-column time: sensor timestamps relative to the first column
    span_us = (fr["col_timestamp_last_ns"] - fr["col_timestamp_first_ns"]) / 1000
    assert s.col_offset_us[0] == 0 and abs(s.col_offset_us[1023] - span_us) <= 1
    assert all(b > a for a, b in zip(s.col_offset_us, s.col_offset_us[1:]))
    # metadata defaults (the reduced file has only angles and lidar_mode), as ouster-sdk
    eff = summ["metadata_effective"]
    assert s.beam_origin_m == pytest.approx(eff["lidar_origin_to_beam_origin_mm"] / 1000, abs=1e-7)
    M = np.array(eff["lidar_to_sensor_transform"], float)
    M[:3, 3] /= 1000
    assert np.allclose(np.array(s.lidar_from_beam).reshape(4, 4), M)
    n, worst = check_oracle_pixels(s, out, "OS-1-64_1024x10_fw20")
    assert n == 8 * 64 and worst < 1e-5
    # a 64 x 1024 sweep with signal and near-IR fits the 600 KB budget
    assert size < 600_000
    c = counters(status[-1])
    assert (c["lidar_packets"], c["imu_packets"], c["frames"], c["frames_incomplete"]) == (64, 11, 1, 0)
    assert sum(v for k, v in c.items() if k.startswith("rejected_")) == 0
    assert status[-1].last_error == ""


def test_os1_64_imu_matches_oracle(tmp_path):
    _, out = ouster(tmp_path, OS1, OS1_META)
    scans, imus, _ = decode(out)
    with open(ORACLE / "OS-1-64_1024x10_fw20_imu_legacy.csv") as f:
        ref = list(csv.DictReader(f))
    assert len(imus) == len(ref) == 11
    g = 9.80665
    for (ts, m), r in zip(imus, ref):
        assert ts == int(r["pcap_ts_sec"]) * 1_000_000 + int(r["pcap_ts_usec"])
        assert m.sensor == "Ouster-imu"
        for i, ax in enumerate("xyz"):
            assert m.accel[i] == pytest.approx(float(r[f"accel_{ax}_g"]) * g, abs=1e-7)
            assert m.gyro[i] == pytest.approx(np.radians(float(r[f"gyro_{ax}_dps"])), abs=1e-8)
    sdk = oracle_summary("OS-1-64_1024x10_fw20")["imu_first_packets_sdk"]
    for (_, m), r in zip(imus, sdk):
        assert np.allclose(m.accel, r["accel"][0], atol=1e-5) and np.allclose(m.gyro, r["gyro"][0], atol=1e-7)
    # one clock for lidar and IMU: differences of utime are differences of sensor time
    t_acc = [int(r["accel_ts_ns"]) for r in ref]
    for (_, a), (_, b), ta, tb in zip(imus, imus[1:], t_acc, t_acc[1:]):
        assert abs((b.utime - a.utime) - (tb - ta) / 1000) <= 1
    first_col = oracle_summary("OS-1-64_1024x10_fw20")["frames"][0]["col_timestamp_first_ns"]
    scan = scans[0][1]
    assert abs((imus[0][1].utime - scan.utime) - (t_acc[0] - first_col) / 1000) <= 1
    # mapped time stays within the capture's time (offset: the first packet's delay here)
    assert all(abs(ts - m.utime) < 20_000 for ts, m in imus)


def test_os2_32_legacy_trimmed_matches_oracle(tmp_path):
    _, out = ouster(tmp_path, OS2_32, OS2_32_META)
    scans, _, status = decode(out)
    assert len(scans) == 1
    s = scans[0][1]
    assert (s.seq, s.rows, s.sensor) == (5424, 32, "OS-2-32-U0")
    n, _ = check_oracle_pixels(s, out, "OS-2-32-U0_v2.0.0_1024x10", cols={0, 1, 255, 256})
    assert n == 4 * 32
    rng = image(s, "range_mm", np.int64)
    assert not rng[:, 272:].any()        # columns of packets not in the trimmed file: no return
    c = counters(status[-1])
    assert (c["frames_incomplete"], c["columns_missing"]) == (1, 1024 - 17 * 16)


def test_os2_128_rng19_trimmed_matches_oracle(tmp_path):
    _, out = ouster(tmp_path, OS2_128, OS2_128_META, "--signal", "on")
    scans, imus, status = decode(out)
    s = scans[0][1]
    assert (s.seq, s.rows, s.cols, s.nsignal) == (1259, 128, 1024, 128 * 1024)
    n, worst = check_oracle_pixels(s, out, "OS-2-128-U1_v2.3.0_1024x10", cols={0, 1})
    assert n == 2 * 128 and worst < 1e-5
    assert len(imus) == 1
    sdk = oracle_summary("OS-2-128-U1_v2.3.0_1024x10")["imu_first_packets_sdk"][0]
    assert np.allclose(imus[0][1].accel, sdk["accel"][0], atol=1e-5)
    # default --signal auto: a 128 x 1024 sweep drops signal and near-IR to stay near the budget
    _, out2 = ouster(tmp_path, OS2_128, OS2_128_META, name="auto.lcm")
    s2 = decode(out2)[0][0][1]
    assert s2.nsignal == 0 and list(s2.range_mm) == list(s.range_mm)


def test_shot_limiting_packet_header(tmp_path):
    p, out = ouster(tmp_path, SHOT, SHOT_META)
    scans, _, status = decode(out)
    s = scans[0][1]
    assert s.seq == 9496 and s.sensor == "OS-0-128"
    rng = image(s, "range_mm", np.int64)
    filled = np.flatnonzero(rng.any(axis=0))
    assert filled.min() >= 16 and filled.max() <= 31
    c = counters(status[-1])
    assert c["packets_shot_limiting"] == 1 and c["packets_thermal_shutdown_alert"] == 1
    assert c["columns_missing"] == 1024 - 16
    assert "shot_limiting 1" in p.stderr and "thermal_shutdown 1 (countdown 5 s)" in p.stderr
    # beam_to_lidar_transform of FW 3.x: x offset is the beam origin
    assert s.beam_origin_m == pytest.approx(0.027116, abs=1e-7)


def expected_meta(path):
    """Independent reading of a metadata file: both layouts, ouster-sdk defaults."""
    d = json.loads(path.read_text())
    def get(key, *sections):
        for sec in sections:
            src = d if sec == "" else d.get(sec)
            if isinstance(src, dict) and key in src:
                return src[key]
        return None
    prod = get("prod_line", "sensor_info", "") or ""
    origin = get("lidar_origin_to_beam_origin_mm", "beam_intrinsics", "")
    if origin is None:
        origin = {"OS-0-": 27.67, "OS-1-": 15.806, "OS-2-": 13.762}.get(prod[:5], 12.163)
    l2s = get("lidar_to_sensor_transform", "lidar_intrinsics", "") or [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 36.18, 0, 0, 0, 1]
    return (get("beam_altitude_angles", "beam_intrinsics", ""), get("beam_azimuth_angles", "beam_intrinsics", ""),
            origin, l2s, prod)


@pytest.mark.parametrize("name", sorted(p.name for p in (DATA / "metadata_os1_64_variants").glob("*.json")))
def test_metadata_variants_flat_and_nested(tmp_path, name):
    meta = DATA / "metadata_os1_64_variants" / name
    p, out = ouster(tmp_path, OS1, meta, "--lidar-port", "7502", "--imu-port", "7503")
    s = decode(out)[0][0][1]
    alt, az, origin, l2s, prod = expected_meta(meta)
    assert s.sensor == prod
    assert np.allclose(s.beam_altitude_rad, np.radians(alt), atol=1e-7)
    assert np.allclose(s.beam_azimuth_rad, -np.radians(az), atol=1e-7)
    assert s.beam_origin_m == pytest.approx(origin / 1000, abs=1e-7)
    M = np.array(l2s, float).reshape(4, 4)
    M[:3, 3] /= 1000
    assert np.allclose(np.array(s.lidar_from_beam).reshape(4, 4), M)
    # the packets do not depend on the calibration
    f = oracle_summary("OS-1-64_1024x10_fw20")["frames"][0]["fields"]
    assert md5(image(s, "range_mm", np.uint32)) == f["RANGE"]["md5_staggered_rowmajor"]


# ---------------------------------------------------------------- frame assembly

def test_lost_packets_leave_empty_columns(tmp_path):
    dg = datagrams(OS1)
    lidar = [i for i, d in enumerate(dg) if d[2] == 7502]
    drop = {lidar[5], lidar[6]}
    pc = tmp_path / "lost.pcap"
    write_udp_pcap(pc, [d for i, d in enumerate(dg) if i not in drop])
    _, full = ouster(tmp_path, OS1, OS1_META, name="full.lcm")
    _, out = ouster(tmp_path, pc, OS1_META)
    a, b = decode(full)[0][0][1], decode(out)[0][0][1]
    ra, rb = image(a, "range_mm", np.int64), image(b, "range_mm", np.int64)
    assert not rb[:, 80:112].any()
    keep = np.r_[0:80, 112:1024]
    assert np.array_equal(ra[:, keep], rb[:, keep])
    # a missing column gets the nominal time (10 Hz x 1024 columns: 97.66 us apart)
    assert [b.col_offset_us[c] for c in (80, 100)] == [int(80 * 1e5 / 1024 + 0.5), int(100 * 1e5 / 1024 + 0.5)]
    c = counters(decode(out)[2][-1])
    assert (c["frames"], c["frames_incomplete"], c["columns_missing"]) == (1, 1, 32)


def renumber(payload, frame_id, dt_ns):
    """A LEGACY packet moved to another frame: frame_id and timestamps of each column."""
    b = bytearray(payload)
    col = len(b) // 16
    for k in range(16):
        o = k * col
        ts = struct.unpack_from("<Q", b, o)[0] + dt_ns
        struct.pack_into("<Q", b, o, ts)
        struct.pack_into("<H", b, o + 10, frame_id)
    return bytes(b)


def test_frames_close_on_new_frame_id_late_and_duplicate_packets(tmp_path):
    dg = [d for d in datagrams(OS1) if d[2] == 7502]
    sec0 = dg[0][0]
    recs = []
    for i, (s, u, p, pl) in enumerate(dg):
        recs.append((s, u, p, pl))
        if i == 3:
            recs.append((s, u, p, pl))                      # duplicate: 16 columns seen twice
    for s, u, p, pl in dg[:32]:                             # frame 190: first half only
        t = s * 1_000_000 + u + 100_000
        recs.append((t // 1_000_000, t % 1_000_000, p, renumber(pl, 190, 100_000_000)))
    recs.append(recs[10])                                   # late: frame 189 already published
    for s, u, p, pl in dg[:16]:                             # frame 191 closes 190
        t = s * 1_000_000 + u + 200_000
        recs.append((t // 1_000_000, t % 1_000_000, p, renumber(pl, 191, 200_000_000)))
    pc = tmp_path / "frames.pcap"
    write_udp_pcap(pc, recs)
    _, out = ouster(tmp_path, pc, OS1_META)
    scans, _, status = decode(out)
    assert [s.seq for _, s, _ in scans] == [189, 190, 191]
    ref = image(scans[0][1], "range_mm", np.int64)
    r190 = image(scans[1][1], "range_mm", np.int64)
    assert np.array_equal(r190[:, :512], ref[:, :512]) and not r190[:, 512:].any()
    assert scans[1][1].utime - scans[0][1].utime == 100_000
    # frame 189 is published when its last column arrives, not later
    assert scans[0][0] == dg[-1][0] * 1_000_000 + dg[-1][1]
    c = counters(status[-1])
    assert c["rejected_column_duplicate"] == 16 and c["rejected_column_late"] == 16
    assert (c["frames"], c["frames_incomplete"]) == (3, 2)


# ---------------------------------------------------------------- bad input

def test_bad_packets_are_counted_not_fatal(tmp_path):
    dg = datagrams(OS1)
    rnd = random.Random(5)
    s0, u0 = dg[0][0], dg[0][1]
    bad = [
        (s0, u0, 7502, dg[0][3][:1000]),                          # truncated
        (s0, u0, 7502, dg[0][3] + b"\0"),                         # one byte too many
        (s0, u0, 7502, bytes(rnd.randrange(256) for _ in range(12608))),   # garbage of the right size
        (s0, u0, 7502, b""),                                      # empty
        (s0, u0, 7503, dg[1][3][:47]),                            # IMU truncated
        (s0, u0, 7503, dg[1][3][:24] + struct.pack("<6f", float("nan"), 0, 1, 0, 0, 0)),
        (s0, u0, 9999, b"x" * 100),                               # another port
    ]
    pc = tmp_path / "bad.pcap"
    write_udp_pcap(pc, bad + dg)
    p, out = ouster(tmp_path, pc, OS1_META)
    scans, imus, status = decode(out)
    c = counters(status[-1])
    assert c["rejected_lidar_wrong_size"] == 3
    assert c["rejected_imu_wrong_size"] == 1 and c["rejected_imu_bad_value"] == 1
    assert len(imus) == 11
    # the garbage packet's columns are invalid (status word), or bad ids, or a frame of their own
    f = oracle_summary("OS-1-64_1024x10_fw20")["frames"][0]["fields"]
    good = [s for _, s, _ in scans if s.seq == 189]
    assert len(good) == 1 and md5(image(good[0], "range_mm", np.uint32)) == f["RANGE"]["md5_staggered_rowmajor"]
    assert "12609 bytes, LEGACY 64x16 per packet expects 12608" in p.stderr
    assert status[-1].state == portobello.status_t.STATE_STOPPING


def test_metadata_that_does_not_match_the_packets(tmp_path):
    # OS1-64 LEGACY packets read with OS2-128 RNG19 metadata: every packet rejected by size
    p, out = ouster(tmp_path, OS1, OS2_128_META)
    scans, imus, status = decode(out)
    c = counters(status[-1])
    assert scans == [] and c["rejected_lidar_wrong_size"] == 64
    assert "the size of LEGACY with 64 rows" in status[-1].last_error
    # right size, other sensor: init_id and prod_sn in the RNG19 header are checked
    meta = json.loads(OS2_128_META.read_text())
    meta["initialization_id"] = 1234
    m2 = tmp_path / "other.json"
    m2.write_text(json.dumps(meta))
    _, out = ouster(tmp_path, OS2_128, m2, name="other.lcm")
    scans, _, status = decode(out)
    assert scans == [] and counters(status[-1])["rejected_lidar_wrong_sensor"] == 8
    _, out = ouster(tmp_path, OS2_128, m2, "--no-sensor-check", name="nocheck.lcm")
    assert len(decode(out)[0]) == 1
    # profile in the metadata says LEGACY for RNG19 packets
    meta["udp_profile_lidar"] = "LEGACY"
    meta["data_format"]["udp_profile_lidar"] = "LEGACY"
    m3 = tmp_path / "legacy.json"
    m3.write_text(json.dumps(meta))
    _, out = ouster(tmp_path, OS2_128, m3, name="legacy.lcm")
    st = decode(out)[2][-1]
    assert counters(st)["rejected_lidar_wrong_size"] == 8
    assert "RNG19_RFL8_SIG16_NIR16 with 128 rows" in st.last_error


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.pop("beam_altitude_angles"), "beam_altitude_angles: missing"),
    (lambda d: d["beam_azimuth_angles"].pop(), "beam_azimuth_angles: 31 values, expected 32"),
    (lambda d: d["data_format"].update(pixels_per_column=64), "beam_altitude_angles: 32 values, expected 64"),
    (lambda d: d.update(lidar_mode="fast"), "lidar_mode"),
    (lambda d: d["data_format"].update(udp_profile_lidar="FUSA_RNG15_RFL8_NIR8_DUAL"), "not supported"),
    (lambda d: d["beam_altitude_angles"].__setitem__(3, "x"), "beam_altitude_angles[3]: not a finite number"),
    (lambda d: d.update(lidar_to_sensor_transform=[1, 0, 0]), "lidar_to_sensor_transform: 3 values, expected 16"),
])
def test_bad_metadata_is_refused_with_the_field(tmp_path, edit, message):
    d = json.loads(OS2_32_META.read_text())
    edit(d)
    m = tmp_path / "m.json"
    m.write_text(json.dumps(d))
    p, out = ouster(tmp_path, OS2_32, m, check=False)
    assert p.returncode == 1 and message in p.stderr, p.stderr


def test_invalid_json_names_the_line(tmp_path):
    m = tmp_path / "m.json"
    m.write_text('{\n "lidar_mode": "1024x10",\n "beam_altitude_angles": [1, 2,,]\n}\n')
    p, _ = ouster(tmp_path, OS1, m, check=False)
    assert p.returncode == 1 and "m.json: line 3" in p.stderr and "not valid JSON" in p.stderr


def test_truncated_capture_keeps_what_was_read(tmp_path):
    d = OS1.read_bytes()
    pc = tmp_path / "cut.pcap"
    pc.write_bytes(d[:len(d) // 2])
    p, out = ouster(tmp_path, pc, OS1_META, check=False)
    assert p.returncode == 1 and "cut short by the end of the file" in p.stderr and "byte " in p.stderr
    scans, imus, status = decode(out)
    assert len(scans) == 1 and len(imus) >= 5     # the partial frame is flushed, the log closed
    assert status[-1].state == portobello.status_t.STATE_ERROR and "byte" in status[-1].last_error
    assert counters(status[-1])["frames_incomplete"] == 1
    (tmp_path / "notpcap.pcap").write_bytes(b"\x0a\x0d\x0d\x0a" + bytes(40))
    p, _ = ouster(tmp_path, tmp_path / "notpcap.pcap", OS1_META, check=False)
    assert p.returncode == 1 and "pcapng" in p.stderr


def fragment(payload_ip, ident, mtu=1500):
    """IPv4 fragments (Ethernet frames) of one UDP datagram, in order."""
    step = (mtu - 20) // 8 * 8
    out = []
    for off in range(0, len(payload_ip), step):
        more = off + step < len(payload_ip)
        out.append(eth_ipv4(payload_ip[off:off + step], ident, (0x2000 if more else 0) | off // 8))
    return out


def test_ipv4_fragments_are_reassembled(tmp_path):
    dg = datagrams(OS2_128)
    _, ref = ouster(tmp_path, OS2_128, OS2_128_META, name="ref.lcm")
    recs = []
    for i, (s, u, port, pl) in enumerate(dg):
        frags = fragment(udp_bytes(port, pl), 100 + i)
        if i % 2:
            frags.reverse()                      # arrival order must not matter
        recs += [(s, u, f) for f in frags]
    assert len(recs) > 100
    pc = tmp_path / "frag.pcap"
    write_pcap(pc, recs)
    _, out = ouster(tmp_path, pc, OS2_128_META)
    a = [(ch, d) for ch, _, d in read_log(ref) if ch != "STATUS"]
    b = [(ch, d) for ch, _, d in read_log(out) if ch != "STATUS"]
    assert a == b
    st = decode(out)[2][-1]
    c = counters(st)
    big = sum(1 for d in dg if len(d[3]) + 8 > 1480)
    assert big == 8 and c["pcap_datagrams_reassembled"] == big
    assert c["pcap_ip_fragments"] == len(recs) - (len(dg) - big)
    # a lost fragment loses its datagram, nothing else
    write_pcap(pc, recs[:5] + recs[6:])
    _, out = ouster(tmp_path, pc, OS2_128_META, name="lost.lcm")
    c = counters(decode(out)[2][-1])
    assert c["pcap_datagrams_reassembled"] == big - 1 and c["columns_missing"] == 1024 - 7 * 16


def test_replay_is_deterministic(tmp_path):
    _, a = ouster(tmp_path, OS1, OS1_META, name="a.lcm")
    _, b = ouster(tmp_path, OS1, OS1_META, name="b.lcm")
    assert a.read_bytes() == b.read_bytes()


# ---------------------------------------------------------------- profiles without captures

def synth_meta(path, profile, rows, init_id=4242, sn=992200000001):
    alt = list(np.linspace(22.5, -22.5, rows).round(3))
    az = [(-1) ** r * 1.2 for r in range(rows)]
    path.write_text(json.dumps({
        "beam_intrinsics": {"beam_altitude_angles": alt, "beam_azimuth_angles": az,
                            "lidar_origin_to_beam_origin_mm": 15.806},
        "config_params": {"lidar_mode": "1024x10", "udp_port_lidar": 7502, "udp_port_imu": 7503},
        "lidar_data_format": {"columns_per_frame": 1024, "columns_per_packet": 16, "pixels_per_column": rows,
                              "pixel_shift_by_row": [0] * rows, "column_window": [0, 1023],
                              "udp_profile_lidar": profile, "udp_profile_imu": "LEGACY"},
        "sensor_info": {"prod_line": "OS-1-%d" % rows, "prod_sn": str(sn), "initialization_id": init_id},
        "lidar_intrinsics": {"lidar_to_sensor_transform": [-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 36.18, 0, 0, 0, 1]},
        "imu_intrinsics": {"imu_to_sensor_transform": [1, 0, 0, 6.253, 0, 1, 0, -11.775, 0, 0, 1, 7.645, 0, 0, 0, 1]},
    }))


def synth_packets(profile, fields, frame_id=7, init_id=4242, sn=992200000001):
    """Non-legacy packets built from the documented layouts (not from the driver's code)."""
    rows = fields["range"].shape[0]
    out = []
    for p in range(64):
        hdr = struct.pack("<HH", 1, frame_id) + init_id.to_bytes(3, "little") + sn.to_bytes(5, "little")
        hdr += bytes(20)
        body = b""
        for k in range(16):
            c = p * 16 + k
            body += struct.pack("<QHH", 1_000_000_000 + c * 97_656, c, 1)
            for r in range(rows):
                if profile == "RNG19_RFL8_SIG16_NIR16_DUAL":
                    w0 = int(fields["range"][r, c]) | 0b10101 << 19 | int(fields["refl"][r, c]) << 24
                    w1 = int(fields["range2"][r, c]) | 0b01010 << 19 | int(fields["refl2"][r, c]) << 24
                    body += struct.pack("<IIHHHH", w0, w1, fields["signal"][r, c], fields["signal2"][r, c],
                                        fields["nir"][r, c], 0xFFFF)
                else:   # RNG15_RFL8_NIR8
                    body += struct.pack("<HBB", int(fields["range"][r, c]) // 8 | 1 << 15, fields["refl"][r, c],
                                        fields["nir"][r, c] // 16)
        out.append(hdr + body + bytes(32))
    return out


def test_dual_return_profile(tmp_path):
    rows, rnd = 32, np.random.default_rng(1)
    f = {k: rnd.integers(0, hi, (rows, 1024)) for k, hi in
         (("range", 1 << 19), ("range2", 1 << 19), ("refl", 256), ("refl2", 256), ("signal", 65536),
          ("signal2", 65536), ("nir", 65536))}
    f["range"][0, :] = 0
    meta = tmp_path / "dual.json"
    synth_meta(meta, "RNG19_RFL8_SIG16_NIR16_DUAL", rows)
    pc = tmp_path / "dual.pcap"
    pk = synth_packets("RNG19_RFL8_SIG16_NIR16_DUAL", f)
    assert len(pk[0]) == 32 + 16 * (12 + rows * 16) + 32 == 8448   # the size of the OS-0-32 DUAL capture
    write_udp_pcap(pc, [(1_700_000_000, i * 1562, 7502, p) for i, p in enumerate(pk)])
    for ret, (rk, fk, sk) in ((1, ("range", "refl", "signal")), (2, ("range2", "refl2", "signal2"))):
        _, out = ouster(tmp_path, pc, meta, "--return", str(ret), name=f"r{ret}.lcm")
        scans, _, status = decode(out)
        s = scans[0][1]
        assert (s.seq, s.rows, s.sensor) == (7, rows, "OS-1-32")
        assert np.array_equal(image(s, "range_mm", np.int64), f[rk])
        assert np.array_equal(image(s, "reflectivity", np.int64), f[fk])
        assert np.array_equal(image(s, "signal", np.uint16), f[sk].astype(np.uint16))
        assert np.array_equal(image(s, "near_ir", np.uint16), f["nir"].astype(np.uint16))
        assert counters(status[-1])["frames_incomplete"] == 0


def test_low_data_rate_profile(tmp_path):
    rows, rnd = 64, np.random.default_rng(2)
    f = {"range": rnd.integers(0, 1 << 15, (rows, 1024)) * 8, "refl": rnd.integers(0, 256, (rows, 1024)),
         "nir": rnd.integers(0, 256, (rows, 1024)) * 16}
    meta = tmp_path / "lr.json"
    synth_meta(meta, "RNG15_RFL8_NIR8", rows)
    pc = tmp_path / "lr.pcap"
    pk = synth_packets("RNG15_RFL8_NIR8", f)
    assert len(pk[0]) == 32 + 16 * (12 + rows * 4) + 32
    write_udp_pcap(pc, [(1_700_000_000, i * 1562, 7502, p) for i, p in enumerate(pk)])
    _, out = ouster(tmp_path, pc, meta)
    s = decode(out)[0][0][1]
    assert np.array_equal(image(s, "range_mm", np.int64), f["range"])
    assert np.array_equal(image(s, "reflectivity", np.int64), f["refl"])
    assert s.nsignal == 0      # no signal in this profile; see docs/ouster.md
    assert s.utime == 1_700_000_000_000_000 - (15 * 97_656 + 1_000_000_000) // 1000 + 1_000_000


# ---------------------------------------------------------------- live UDP on loopback

@pytest.mark.live
def test_live_udp_replay_on_loopback(tmp_path):
    import lcm
    lidar_port, imu_port = 7801, 7802
    got = {"LIDAR_SCAN": [], "IMU": [], "STATUS": []}
    lc = lcm.LCM(LCM_URL)
    for ch in got:
        lc.subscribe(ch, lambda c, d: got[c].append(d))
    proc = subprocess.Popen([str(BIN / "ouster"), "--metadata", str(OS1_META), "--lcm-url", LCM_URL,
                             "--lidar-port", str(lidar_port), "--imu-port", str(imu_port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop = threading.Event()

    def pump():
        while not stop.is_set():
            lc.handle_timeout(50)
    th = threading.Thread(target=pump)
    th.start()
    try:
        time.sleep(0.5)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        dg = datagrams(OS1)
        for s, u, port, pl in dg:
            tx.sendto(pl, ("127.0.0.1", lidar_port if port == 7502 else imu_port))
            if port == 7503:
                tx.sendto(b"\x01" * 5, ("127.0.0.1", lidar_port))
            time.sleep(0.001)
        # half of frame 190, then silence: published after 1.5 frame periods
        for s, u, port, pl in [d for d in dg if d[2] == 7502][:32]:
            tx.sendto(renumber(pl, 190, 100_000_000), ("127.0.0.1", lidar_port))
        deadline = time.time() + 5
        while time.time() < deadline and (len(got["LIDAR_SCAN"]) < 2 or len(got["IMU"]) < 11 or not got["STATUS"]):
            time.sleep(0.05)
        time.sleep(1.2)     # one more heartbeat, with the counts
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
        stop.set()
        th.join()
    assert proc.returncode == 0, err
    assert len(got["LIDAR_SCAN"]) == 2 and len(got["IMU"]) == 11
    s2 = portobello.lidar_scan_t.decode(got["LIDAR_SCAN"][1])
    r2 = image(s2, "range_mm", np.int64)
    assert s2.seq == 190 and r2[:, :512].any() and not r2[:, 512:].any()
    s = portobello.lidar_scan_t.decode(got["LIDAR_SCAN"][0])
    f = oracle_summary("OS-1-64_1024x10_fw20")["frames"][0]["fields"]
    assert s.seq == 189 and md5(image(s, "range_mm", np.uint32)) == f["RANGE"]["md5_staggered_rowmajor"]
    # live time: sensor time mapped to the wall clock of this run
    assert abs(s.utime - time.time() * 1e6) < 60e6
    st = [portobello.status_t.decode(d) for d in got["STATUS"]]
    assert all(x.module == "ouster" for x in st)
    c = counters(st[-1])
    assert c["lidar_packets"] == 64 + 11 + 32 and c["rejected_lidar_wrong_size"] == 11
    assert c["frames"] == 2 and c["frames_incomplete"] == 1
    assert "5 bytes" in st[-1].last_error


# ---------------------------------------------------------------- full captures (optional)

@pytest.mark.real
@pytest.mark.parametrize("name,meta,signal", [
    ("OS-2-32-U0_v2.0.0_1024x10", "OS-2-32-U0_v2.0.0_1024x10.json", "auto"),
    ("OS-2-128-U1_v2.3.0_1024x10", "OS-2-128-U1_v2.3.0_1024x10.json", "on"),
    ("OS-1-64_1024x10_fw20", "OS-1-64_sensor_config_reduced.json", "auto"),
])
def test_real_full_frames_match_oracle(tmp_path, name, meta, signal):
    if not REAL.is_dir():
        pytest.skip(f"{REAL} is absent")
    _, out = ouster(tmp_path, REAL / f"{name}.pcap", REAL / meta, "--signal", signal)
    scans, imus, status = decode(out)
    summ = json.loads((REAL / "oracle" / f"{name}_oracle_summary.json").read_text())
    fr = summ["frames"][0]
    s = scans[0][1]
    assert len(scans) == 1 and s.seq == fr["frame_id"]
    for field, key, dt in (("range_mm", "RANGE", np.uint32), ("signal", "SIGNAL", np.uint16),
                           ("reflectivity", "REFLECTIVITY", np.uint8), ("near_ir", "NEAR_IR", np.uint16)):
        assert md5(image(s, field, dt)) == fr["fields"][key]["md5_staggered_rowmajor"], field
    digest = REAL / f"{name}_digest.json"
    if digest.exists():
        d = json.loads(digest.read_text())["scans"][0]
        assert md5(image(s, "range_mm", np.uint32)) == d["RANGE"]
    c = counters(status[-1])
    assert (c["lidar_packets"], c["imu_packets"], c["frames_incomplete"]) == (64, summ["imu_packets"], 0)
    assert len(imus) == summ["imu_packets"]
    n, worst = check_oracle_pixels(s, out, name)
    assert n == 8 * s.rows and worst < 1e-5
    pts = points(out)
    assert len(pts) == fr["fields"]["RANGE"]["nonzero"]
    # every point: the sum of xyz over the frame (6-decimal CSV) as ouster-sdk's
    xyz = np.array(list(pts.values()), float).sum(axis=0)
    assert np.allclose(xyz, fr["xyz_sum_m"], rtol=0, atol=0.01)
