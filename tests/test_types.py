"""Every LCM type round-trips: Python encode/decode, and C decode/re-encode of the
same bytes; a full 64x1024 LiDAR sweep fits the 600 KB budget."""
import random
import struct

import pytest

import portobello
from conftest import BUILD, read_log, run

TYPES = sorted(n for n in dir(portobello) if n.endswith("_t"))
INT_RANGES = {"int8_t": 7, "int16_t": 15, "int32_t": 31, "int64_t": 63}


def scalar(rng, typename):
    if typename in INT_RANGES:
        b = INT_RANGES[typename]
        return rng.randint(-(1 << b), (1 << b) - 1)
    if typename == "byte":
        return rng.randint(0, 255)
    if typename == "boolean":
        return rng.random() < 0.5
    if typename == "float":
        return struct.unpack("f", struct.pack("f", rng.uniform(-1e6, 1e6)))[0]
    if typename == "double":
        return rng.uniform(-1e9, 1e9)
    if typename == "string":
        return "".join(rng.choice("abcXYZ _-:/0123456789") for _ in range(rng.randint(0, 12)))
    return fill(getattr(portobello, typename.split(".")[-1])(), rng)


def fill(msg, rng):
    """Fills every field with random values; dimension fields get small counts."""
    dims = {d for ds in msg.__dimensions__ if ds for d in ds if isinstance(d, str)}
    for name, typ in zip(msg.__slots__, msg.__typenames__):
        if name in dims:
            setattr(msg, name, rng.randint(0, 4))
    for name, typ, ds in zip(msg.__slots__, msg.__typenames__, msg.__dimensions__):
        if name in dims:
            continue
        if ds is None:
            setattr(msg, name, scalar(rng, typ))
        else:
            n = ds[0] if isinstance(ds[0], int) else getattr(msg, ds[0])
            setattr(msg, name, [scalar(rng, typ) for _ in range(n)])
    return msg


def same(a, b):
    if hasattr(a, "__slots__"):
        return all(same(getattr(a, s), getattr(b, s)) for s in a.__slots__)
    if isinstance(a, (list, tuple, bytes, bytearray)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def test_all_channel_types_exist():
    for t in ["lidar_scan_t", "imu_t", "can_frame_t", "vehicle_speed_t", "gnss_fix_t", "pose_t", "head_pose_t",
              "agents_t", "occlusion_t", "scenario_event_t", "participant_input_t", "status_t"]:
        assert t in TYPES


@pytest.mark.parametrize("name", TYPES)
def test_python_roundtrip(name):
    rng = random.Random(name)
    cls = getattr(portobello, name)
    for _ in range(20):
        msg = fill(cls(), rng)
        data = msg.encode()
        back = cls.decode(data)
        assert same(msg, back)
        assert back.encode() == data


def test_c_roundtrip_reproduces_python_bytes(tmp_path):
    import lcm
    rng = random.Random(7)
    src, dst = tmp_path / "py.lcm", tmp_path / "c.lcm"
    log = lcm.EventLog(str(src), "w", overwrite=True)
    sent = []
    for name in TYPES:
        for _ in range(10):
            data = fill(getattr(portobello, name)(), rng).encode()
            log.write_event(len(sent), name, data)
            sent.append((name, data))
    log.close()
    p = run([BUILD / "tests" / "types_roundtrip", src, dst])
    assert f"{len(sent)} messages round-tripped" in p.stdout
    back = list(read_log(dst))
    assert len(back) == len(sent)
    for (name, data), (ch, _, cdata) in zip(sent, back):
        assert ch == name
        assert cdata == data, name


def test_full_ouster_sweep_fits_600_kb():
    """64 x 1024 with every optional array filled (signal and near-IR too)."""
    rows, cols = 64, 1024
    s = portobello.lidar_scan_t()
    s.rows, s.cols, s.npixels, s.nsignal = rows, cols, rows * cols, rows * cols
    s.range_mm = [123456] * s.npixels
    s.reflectivity = [200] * s.npixels
    s.signal = [-1] * s.npixels
    s.near_ir = [1000] * s.npixels
    s.col_offset_us = list(range(0, 100000, 100000 // cols))[:cols]
    s.beam_altitude_rad = [0.1] * rows
    s.beam_azimuth_rad = [0.01] * rows
    s.lidar_from_beam = [0.0] * 16
    s.sensor = "OS1-64"
    size = len(s.encode())
    assert size <= 600_000, size
