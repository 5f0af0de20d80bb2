"""The importers: import-candump (candump -l -> CAN_FRAME), import-scans (scan
folders + poses -> LIDAR_SCAN + GROUND_TRUTH + map) and build-map (log -> map).

Fast tests use the trimmed real data committed in tests/data (RAV4 CAN from
comma2k19, the HDL-32E pair from fast_gicp) and small files written here. The
`real` tests read ../shared/data (the full RAV4 log, MulRan) and run only with
`make test-real`."""
import math
import os
import random
import re
import shutil

import numpy as np
import pytest

import portobello
from conftest import BIN, ROOT, SHARED_DATA, read_log, run

DATA = ROOT / "tests" / "data"
CAN_SAMPLE = DATA / "can_rav4" / "rav4_seg40_first2s.candump.log"
HDL = DATA / "lidar_pair_hdl32"
HDL_TARGET, HDL_SOURCE = "251370668", "251371071"
T0 = 1_700_000_000_000_000
WALL_X = 30.07  # off the 0.15 m voxel boundaries, so the voxel count is exact


# ---------------------------------------------------------------- helpers

def parse_candump_line(line):
    """Reference parser for the plain lines of the RAV4 sample: (utime, bus, id, data)."""
    m = re.fullmatch(r"\((\d+)\.(\d{6})\) can(\d+) ([0-9A-F]{3})#([0-9A-F]*)", line.strip())
    assert m, line
    return (int(m[1]) * 1_000_000 + int(m[2]), int(m[3]), int(m[4], 16), bytes.fromhex(m[5]))


def can_frames(path):
    out = []
    for ch, ts, data in read_log(path):
        assert ch == "CAN_FRAME"
        f = portobello.can_frame_t.decode(data)
        assert ts == f.utime
        out.append(f)
    return out


def read_pcd(path):
    """Minimal PCD reader for binary float32 files: (fields, N x F array)."""
    raw = pathlib_bytes(path)
    header, pos = {}, 0
    while True:
        end = raw.index(b"\n", pos)
        line = raw[pos:end].decode().strip()
        pos = end + 1
        if line.startswith("#") or not line:
            continue
        key, *vals = line.split()
        header[key] = vals
        if key == "DATA":
            break
    assert header["DATA"] == ["binary"], header
    assert all(t == "F" for t in header["TYPE"]) and all(s == "4" for s in header["SIZE"])
    n = int(header["POINTS"][0])
    arr = np.frombuffer(raw[pos:pos + n * 4 * len(header["FIELDS"])], dtype="<f4")
    return header["FIELDS"], arr.reshape(n, len(header["FIELDS"]))


def pathlib_bytes(path):
    with open(path, "rb") as f:
        return f.read()


def quat_from_matrix(R):
    """w, x, y, z of a rotation matrix (w >= 0)."""
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    if w > 1e-3:
        q = [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)]
    else:  # not needed by these tests' rotations
        raise ValueError("rotation near 180 deg")
    return np.array(q)


def matrix_from_quat(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def same_rotation(qa, qb, tol=1e-9):
    return abs(abs(float(np.dot(qa, qb))) - 1.0) < tol


def scans_and_truth(path):
    scans, truth = [], []
    for ch, ts, data in read_log(path):
        if ch == "LIDAR_SCAN":
            s = portobello.lidar_scan_t.decode(data)
            assert ts == s.utime
            scans.append(s)
        elif ch == "GROUND_TRUTH":
            p = portobello.pose_t.decode(data)
            assert ts == p.utime
            truth.append(p)
    return scans, truth


def scan_array(s):
    return np.stack([np.array(s.x, dtype=np.float32), np.array(s.y, dtype=np.float32),
                     np.array(s.z, dtype=np.float32), np.array(s.intensity, dtype=np.float32)], axis=1)


def voxel_keys(points, voxel):
    return np.unique(np.floor(points[:, :3].astype(np.float64) / voxel).astype(np.int64), axis=0)


# ---------------------------------------------------------------- import-candump

def test_candump_sample_keeps_every_frame(tmp_path):
    out = tmp_path / "can.lcm"
    run([BIN / "import-candump", "--in", CAN_SAMPLE, "--out", out, "--quiet"])
    lines = CAN_SAMPLE.read_text().splitlines()
    frames = can_frames(out)
    assert len(frames) == len(lines) == 4516
    for f, line in zip(frames, lines):          # every frame, in file order
        utime, bus, can_id, data = parse_candump_line(line)
        assert (f.utime, f.bus, f.id, bytes(f.data), f.len) == (utime, bus, can_id, data, len(data)), line
        assert not (f.extended or f.rtr or f.error or f.fd)
    # first and last against the text, spelled out
    assert (frames[0].utime, frames[0].bus, frames[0].id, bytes(frames[0].data)) == \
        (1533226488434433, 0, 0x260, bytes.fromhex("08FFFB0000001884"))
    last = parse_candump_line(lines[-1])
    assert (frames[-1].utime, frames[-1].bus, frames[-1].id, bytes(frames[-1].data)) == last
    assert {f.bus for f in frames} == {0, 1, 128, 129}


def test_candump_frame_forms(tmp_path):
    src = tmp_path / "forms.log"
    src.write_text(
        "(1600000000.000001) can0 123#DEADBEEF\n"
        "(1600000000.000002) can1 1ABCDEF0#0102030405060708\n"   # 29-bit
        "(1600000000.000003) can0 7FF#R\n"                       # remote, len 0
        "(1600000000.000004) can0 321#R5\n"                      # remote, requests 5 bytes
        "(1600000000.000005) can2 456##1" + "11" * 12 + "\n"    # CAN FD, BRS, 12 bytes
        "(1600000000.000006) can0 20000080#0000000000000000\n"   # error frame (CAN_ERR_FLAG)
        "(1600000000.000007) vcan0 010#11.22.33\n"               # '.' separators, named interface
        "(1600000000.000008) slcan0 011#\n"                      # zero-length
        "(1600000000.000009) vcan0 012#0102030405060708_C T\n"   # len8_dlc, direction flag
        "\n"                                                     # blank lines are not frames
        "(1600000001.5) can0 013#AA\n")                          # short fraction = 500000 us
    out = tmp_path / "forms.lcm"
    p = run([BIN / "import-candump", "--in", src, "--out", out])
    assert "vcan0 -> bus 1000" in p.stderr and "slcan0 -> bus 1001" in p.stderr
    f = can_frames(out)
    assert len(f) == 10
    assert [x.utime for x in f] == [1600000000000000 + k for k in range(1, 10)] + [1600000001500000]
    assert (f[0].bus, f[0].id, bytes(f[0].data), f[0].extended) == (0, 0x123, bytes.fromhex("DEADBEEF"), False)
    assert (f[1].bus, f[1].id, f[1].extended, f[1].len) == (1, 0x1ABCDEF0, True, 8)
    assert (f[2].id, f[2].rtr, f[2].len) == (0x7FF, True, 0)
    assert (f[3].rtr, f[3].len, bytes(f[3].data)) == (True, 5, bytes(5))
    assert (f[4].bus, f[4].fd, f[4].len, bytes(f[4].data)) == (2, True, 12, b"\x11" * 12)
    assert (f[5].error, f[5].extended, f[5].id, f[5].len) == (True, False, 0x80, 8)
    assert (f[6].bus, bytes(f[6].data)) == (1000, b"\x11\x22\x33")
    assert (f[7].bus, f[7].len) == (1001, 0)
    assert (f[8].bus, f[8].len) == (1000, 8)


@pytest.mark.parametrize("bad, col_what", [
    ("(1533226489.000000) can0 0B4#00000000001D0B7A5E", "bad length"),   # 9 bytes
    ("(1533226489.000000) can0 0B4#0000000Z", "bad data"),
    ("(1533226489.000000) can0 8B4#00", "bad CAN id"),                   # > 7FF
    ("(1533226489.0000000) can0 0B4#00", "bad timestamp"),               # 7 fractional digits
    ("1533226489.000000 can0 0B4#00", "bad timestamp"),
    ("(1533226489.000000) can0 0B4#00 extra", "unexpected text"),
    ("(1533226489.000000) can0 0B4##00", "bad data"),                    # FD without flags digit... '0' then odd '0'
    ("(1533226489.000000) can0 0B4###00", "CAN XL"),
])
def test_candump_corrupt_line_stops_with_file_line(tmp_path, bad, col_what):
    lines = CAN_SAMPLE.read_text().splitlines(keepends=True)[:3000]
    bad_at = 2000                                # 1-based line number of the corrupt line
    src = tmp_path / "corrupt.log"
    src.write_text("".join(lines[:bad_at - 1]) + bad + "\n" + "".join(lines[bad_at:]))
    out = tmp_path / "corrupt.lcm"
    p = run([BIN / "import-candump", "--in", src, "--out", out], check=False)
    assert p.returncode == 1, p.stderr
    assert f"{src}:{bad_at}:" in p.stderr and col_what in p.stderr, p.stderr
    frames = can_frames(out)                     # reads back cleanly
    assert len(frames) == bad_at - 1
    for f, line in zip(frames, lines):
        assert (f.utime, f.bus, f.id, bytes(f.data)) == parse_candump_line(line)


def test_candump_parser_survives_garbage(tmp_path):
    """Mutated and random lines: the tool either imports or stops with file:line, never crashes."""
    rng = random.Random(1234)
    good = CAN_SAMPLE.read_text().splitlines()[:50]
    alphabet = b"()0123456789.#R_ABCDEFabcdefxz \t\r\x00\xff"
    for k in range(120):
        base = bytearray(rng.choice(good).encode())
        if k % 3 == 0:
            line = bytes(rng.choice(alphabet) for _ in range(rng.randint(0, 80)))
        else:
            for _ in range(rng.randint(1, 4)):
                op = rng.randrange(3)
                i = rng.randrange(len(base) + 1)
                if op == 0 and base:
                    del base[min(i, len(base) - 1)]
                elif op == 1:
                    base.insert(i, rng.choice(alphabet))
                elif base:
                    base[min(i, len(base) - 1)] = rng.randrange(256)
            line = bytes(base)
        src = tmp_path / f"g{k}.log"
        src.write_bytes(good[0].encode() + b"\n" + line + b"\n")
        out = tmp_path / f"g{k}.lcm"
        p = run([BIN / "import-candump", "--in", src, "--out", out, "--quiet"], check=False, errors="replace")
        assert p.returncode in (0, 1), (line, p.returncode, p.stderr)
        if p.returncode == 1:
            assert f"{src}:2:" in p.stderr, p.stderr
        assert len(can_frames(out)) >= 1


def test_candump_help_and_usage():
    p = run([BIN / "import-candump", "--help"])
    assert "candump" in p.stdout and "--channel" in p.stdout
    p = run([BIN / "import-candump", "--in", CAN_SAMPLE], check=False)
    assert p.returncode == 2 and "--out" in p.stderr


# ---------------------------------------------------------------- import-scans: the HDL-32E pair

@pytest.fixture(scope="module")
def hdl_import(tmp_path_factory):
    d = tmp_path_factory.mktemp("hdl")
    scans = d / "scans"
    scans.mkdir()
    for name in (HDL_TARGET, HDL_SOURCE):
        shutil.copy(HDL / f"{name}.pcd", scans / f"{name}.pcd")
    T = np.loadtxt(HDL / "relative.txt")            # target <- source
    poses = d / "poses.txt"
    # KITTI 3x4 rows: the target scan defines the map frame, the source sits at relative.txt.
    rows = [np.eye(4)[:3].ravel(), T[:3].ravel()]
    poses.write_text("".join(" ".join(repr(float(v)) for v in r) + "\n" for r in rows))
    site = d / "site"
    out = d / "pair.lcm"
    p = run([BIN / "import-scans", "--scans", scans, "--poses", poses, "--out", out,
             "--map-out", site / "map.pcd", "--voxel", "0.2"])
    return dict(dir=d, out=out, site=site, T=T, stderr=p.stderr)


def test_hdl_pair_scans_reproduce_the_pcds(hdl_import):
    scans, truth = scans_and_truth(hdl_import["out"])
    assert len(scans) == len(truth) == 2
    for s, name, n in zip(scans, (HDL_TARGET, HDL_SOURCE), (69088, 69792)):
        fields, ref = read_pcd(HDL / f"{name}.pcd")
        assert fields == ["x", "y", "z", "intensity"]
        assert s.npoints == n == len(ref)
        got = scan_array(s)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[-1], ref[-1])
        assert np.array_equal(got, ref)            # every value, bit for bit
        assert (s.rows, s.cols, s.npixels, s.nsignal) == (0, 0, 0, 0)
        assert set(s.ring) == {255} and set(s.point_offset_us) == {0}
    # 10 Hz from the fixed epoch when neither --times nor TUM times are given
    assert [s.utime for s in scans] == [1577836800_000000, 1577836800_100000]


def test_hdl_pair_ground_truth_equals_poses(hdl_import):
    _, truth = scans_and_truth(hdl_import["out"])
    T = hdl_import["T"]
    a, b = truth
    assert np.allclose(a.position, [0, 0, 0], atol=1e-12) and same_rotation(a.orientation, [1, 0, 0, 0])
    assert np.allclose(b.position, T[:3, 3], atol=1e-9)
    assert np.allclose(matrix_from_quat(b.orientation), T[:3, :3], atol=2e-5)   # relative.txt has 6 digits
    for p in truth:
        assert p.source == portobello.pose_t.SOURCE_GROUND_TRUTH
        assert p.status == portobello.pose_t.STATUS_TRACKING



def test_hdl_pair_ground_truth_is_the_base_pose_with_a_vehicle_file(hdl_import, tmp_path):
    """With --vehicle, GROUND_TRUTH = map <- lidar * lidar <- base; the scans are unchanged."""
    veh = ROOT / "vehicles" / "prius2017.yaml"
    d = hdl_import["dir"]
    out = tmp_path / "base.lcm"
    run([BIN / "import-scans", "--scans", d / "scans", "--poses", d / "poses.txt", "--out", out,
         "--vehicle", veh, "--quiet"])
    scans, truth = scans_and_truth(out)
    ref_scans, _ = scans_and_truth(hdl_import["out"])
    assert [s.npoints for s in scans] == [s.npoints for s in ref_scans]
    lidar_xyz = np.array([1.10, 0.0, 1.95])     # vehicles/prius2017.yaml, rpy 0
    T = hdl_import["T"]
    for p, M in zip(truth, (np.eye(4), T)):
        # base origin = lidar pose applied to (-lidar_xyz) in the lidar frame
        want = M[:3, :3] @ (-lidar_xyz) + M[:3, 3]
        assert np.allclose(p.position, want, atol=1e-6)
        assert np.allclose(matrix_from_quat(p.orientation), M[:3, :3], atol=2e-5)

def test_hdl_pair_map_with_a_vehicle_file_is_the_same_map(hdl_import, tmp_path):
    """--vehicle changes GROUND_TRUTH (base), never the map: the points are the LiDAR's and
    are placed with the LiDAR pose (the map was once placed with the base pose, 1.95 m low
    with the Prius file, 1.8 m with lidar_mast: every real start then fitted a sunken map)."""
    d = hdl_import["dir"]
    site = tmp_path / "site"
    run([BIN / "import-scans", "--scans", d / "scans", "--poses", d / "poses.txt", "--out", tmp_path / "b.lcm",
         "--vehicle", ROOT / "vehicles" / "prius2017.yaml", "--map-out", site / "map.pcd", "--voxel", "0.2",
         "--quiet"])
    _, want = read_pcd(hdl_import["site"] / "map.pcd")
    _, got = read_pcd(site / "map.pcd")
    assert got.shape == want.shape
    assert np.allclose(np.sort(got[:, 2]), np.sort(want[:, 2]), atol=1e-6)
    assert np.allclose(got.mean(axis=0), want.mean(axis=0), atol=1e-6)


def test_hdl_pair_point_times_from_azimuth(hdl_import, tmp_path):
    """The real HDL-32E sweeps carry no point times. Their PCD holds the points in firing
    order (32 beams a firing, turning clockwise), so --spin cw finds where each sweep starts
    and gives the points 0-100 ms; the other way round is an error naming the turn."""
    d = hdl_import["dir"]
    out = tmp_path / "spun.lcm"
    p = run([BIN / "import-scans", "--scans", d / "scans", "--poses", d / "poses.txt", "--out", out, "--spin", "cw"])
    assert "no point times" not in p.stderr
    for s in scans_and_truth(out)[0]:
        t = np.array(s.point_offset_us)
        az = np.degrees(np.arctan2(np.array(s.y), np.array(s.x)))
        assert t[0] == 0 and t.min() == 0 and 99000 <= t.max() <= 100000, (t[0], t.max())
        # clockwise: a point a quarter turn on from the first (90 degrees less) at 25 ms
        quarter = np.abs(((az[0] - az) % 360) - 90) < 0.5
        assert quarter.sum() > 100 and np.all(np.abs(t[quarter] - 25000) < 200)
    p = run([BIN / "import-scans", "--scans", d / "scans", "--poses", d / "poses.txt", "--out", out, "--spin", "ccw"],
            check=False)
    assert p.returncode == 1 and "its points turn clockwise" in p.stderr, p.stderr


def test_hdl_pair_map_is_the_aligned_union(hdl_import):
    site = hdl_import["site"]
    assert sorted(os.listdir(site)) == ["map.pcd"]          # loadable as a site
    fields, m = read_pcd(site / "map.pcd")
    assert fields == ["x", "y", "z", "intensity"]
    T = hdl_import["T"]
    _, tgt = read_pcd(HDL / f"{HDL_TARGET}.pcd")
    _, src = read_pcd(HDL / f"{HDL_SOURCE}.pcd")
    src_map = src[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    union = np.vstack([tgt[:, :3].astype(np.float64), src_map])
    lo, hi = union.min(axis=0), union.max(axis=0)
    assert np.all(m[:, :3] >= lo - 1e-3) and np.all(m[:, :3] <= hi + 1e-3)
    # One point per occupied 0.2 m voxel of the union (centroids stay in their voxel).
    v = 0.2
    n_union = len(voxel_keys(union, v))
    assert abs(len(m) - n_union) <= max(3, n_union // 1000), (len(m), n_union)
    assert len(voxel_keys(m, v)) >= len(m) - 2        # centroids stay in their voxel (float rounding aside)
    # The scans overlap once aligned: fewer voxels than both scans apart, and fewer
    # than with the source left unaligned (pose ignored).
    n_t, n_s = len(voxel_keys(tgt, v)), len(voxel_keys(src_map, v))
    assert len(m) < n_t + n_s
    n_unaligned = len(voxel_keys(np.vstack([tgt[:, :3], src[:, :3]]), v))
    assert n_union < n_unaligned
    assert max(n_t, n_s) < len(m)
    # The pair writes (0, 0, 0) for no return (5,032 and 5,107 points): none of them in the
    # map, where they would stand at the sensor's origin, 1.9 m above the road
    assert (tgt[:, :3] == 0).all(axis=1).sum() == 5032
    for origin in (np.zeros(3), T[:3, 3]):
        assert np.linalg.norm(m[:, :3] - origin, axis=1).min() > 0.05


# ---------------------------------------------------------------- import-scans: KITTI .bin, formats, errors

def write_bin(path, pts):
    np.asarray(pts, dtype="<f4").tofile(path)


def rot_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def make_bin_scans(d, n=3):
    d.mkdir()
    rng = np.random.default_rng(7)
    scans = []
    for k in range(n):
        pts = rng.uniform(-20, 20, size=(50 + k, 4)).astype("<f4")
        if k == 1:
            pts[10, 0] = np.nan                      # dropped and counted
            pts[11, 2] = np.inf
        write_bin(d / f"{k:06d}.bin", pts)
        scans.append(pts)
    return scans


def test_kitti_bin_with_calib_and_times(tmp_path):
    scans = make_bin_scans(tmp_path / "velodyne")
    # KITTI camera poses and a calib: the LiDAR pose is Tr^-1 * P * Tr.
    Tr = np.eye(4)
    Tr[:3, :3] = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0.0]])    # velo (x fwd, z up) -> cam (z fwd, y down)
    Tr[:3, 3] = [0.27, -0.08, -0.01]
    Ps = []
    for k in range(3):
        P = np.eye(4)
        P[:3, :3] = rot_z(5.0 * k)
        P[:3, 3] = [0.1 * k, -0.2 * k, 1.5 * k]
        Ps.append(P)
    (tmp_path / "poses.txt").write_text(
        "".join(" ".join("%.9f" % v for v in P[:3].ravel()) + "\n" for P in Ps))
    (tmp_path / "calib.txt").write_text(
        "P0: 7.1e2 0 6.0e2 0 0 7.1e2 1.8e2 0 0 0 1 0\n"
        "Tr: " + " ".join("%.9f" % v for v in Tr[:3].ravel()) + "\n")
    (tmp_path / "times.txt").write_text("1565943983.5248752\n1565943984.0000004\n1565943984.5\n")
    out = tmp_path / "k.lcm"
    p = run([BIN / "import-scans", "--scans", tmp_path / "velodyne", "--poses", tmp_path / "poses.txt",
             "--calib", tmp_path / "calib.txt", "--times", tmp_path / "times.txt", "--out", out])
    assert "2 non-finite points dropped" in p.stderr
    got, truth = scans_and_truth(out)
    assert [s.npoints for s in got] == [50, 49, 52]
    # times: 7th fractional digit rounds to the microsecond
    assert [s.utime for s in got] == [1565943983524875, 1565943984000000, 1565943984500000]
    assert [t.utime for t in truth] == [s.utime for s in got]
    keep = np.all(np.isfinite(scans[1][:, :3]), axis=1)
    assert np.array_equal(scan_array(got[1]), scans[1][keep])
    assert np.array_equal(scan_array(got[0])[[0, -1]], scans[0][[0, -1]])
    Tri = np.linalg.inv(Tr)
    for P, t in zip(Ps, truth):
        L = Tri @ P @ Tr
        assert np.allclose(t.position, L[:3, 3], atol=1e-7)
        assert np.allclose(matrix_from_quat(t.orientation), L[:3, :3], atol=1e-7)
    # finite-difference velocity of the middle pose
    v = (Tri @ Ps[2] @ Tr)[:3, 3] - (Tri @ Ps[0] @ Tr)[:3, 3]
    assert np.allclose(truth[1].velocity, v / (1565943984.5 - 1565943983.5248752), rtol=1e-5)


def test_every_and_first_split_a_sequence(tmp_path):
    """--every 2 for the map's scans, --every 2 --first 1 for the others to localize in it."""
    scans = make_bin_scans(tmp_path / "s", n=5)
    (tmp_path / "p.txt").write_text("".join(f"1 0 0 {k} 0 1 0 0 0 0 1 0\n" for k in range(5)))
    got = {}
    for first in (0, 1):
        out = tmp_path / f"x{first}.lcm"
        run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "p.txt", "--out", out,
             "--every", "2", "--first", str(first)])
        got[first] = scans_and_truth(out)
    assert [t.position[0] for t in got[0][1]] == [0, 2, 4] and [t.position[0] for t in got[1][1]] == [1, 3]
    assert [s.utime for s in got[1][0]] == [t.utime for t in got[1][1]]
    keep = np.all(np.isfinite(scans[1][:, :3]), axis=1)
    assert np.array_equal(scan_array(got[1][0][0]), scans[1][keep])
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "p.txt", "--out", tmp_path / "y.lcm",
             "--first", "5"], check=False)
    assert p.returncode == 1 and "no scan to import: 5 scans pair with poses and times, and --first is 5" in p.stderr


def test_tum_poses_give_times(tmp_path):
    make_bin_scans(tmp_path / "s", n=2)
    (tmp_path / "tum.txt").write_text(
        "# timestamp tx ty tz qx qy qz qw\n"
        "1700000000.25 1 2 3 0 0 0 1\n"
        "1700000000.35 4 5 6 0 0 0.7071067811865476 0.7071067811865476\n")
    out = tmp_path / "t.lcm"
    run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "tum.txt", "--out", out])
    _, truth = scans_and_truth(out)
    assert [t.utime for t in truth] == [1700000000250000, 1700000000350000]
    assert np.allclose(truth[1].position, [4, 5, 6])
    assert same_rotation(truth[1].orientation, [math.sqrt(0.5), 0, 0, math.sqrt(0.5)])


def test_timed_poses_are_interpolated_at_the_scan_times(tmp_path):
    """Ground truth at its own instants (an INS, MulRan's global_pose.csv: nanoseconds, a
    3x4, commas): each scan takes the pose at its --times instant; scans before, after or
    in a gap of over 1 s are left out and counted."""
    make_bin_scans(tmp_path / "s", n=6)
    t0 = 1566000000.0
    pose_at = {0.0: 0, 0.1: 1, 0.2: 2, 0.3: 3, 2.0: 4, 3.5: 5}     # s after t0: yaw 10 deg/s, x 10 m/s
    rows = []
    for dt in pose_at:
        R = rot_z(10.0 * dt)
        M = np.hstack([R, [[10.0 * dt], [0.0], [1.5]]])
        rows.append("%d," % round((t0 + dt) * 1e9) + ",".join("%.12f" % v for v in M.ravel()))
    (tmp_path / "global_pose.csv").write_text("\n".join(rows) + "\n")
    scan_dt = [-0.5, 0.05, 0.15, 0.25, 1.0, 4.0]
    (tmp_path / "times.txt").write_text("".join("%.6f\n" % (t0 + dt) for dt in scan_dt))
    out = tmp_path / "i.lcm"
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "global_pose.csv",
             "--times", tmp_path / "times.txt", "--out", out])
    assert "3 of 6 scans have no pose at their time" in p.stderr, p.stderr
    assert "1 before its first, 1 after its last, 1 in gaps over 1.0 s" in p.stderr, p.stderr
    scans, truth = scans_and_truth(out)
    assert [s.npoints for s in scans] == [49, 52, 53]                 # scans 1 (51, a NaN and an inf dropped), 2, 3
    assert [t.utime for t in truth] == [round((t0 + dt) * 1e6) for dt in (0.05, 0.15, 0.25)]
    for dt, t in zip((0.05, 0.15, 0.25), truth):
        assert np.allclose(t.position, [10.0 * dt, 0, 1.5], atol=1e-9)
        assert np.allclose(matrix_from_quat(t.orientation), rot_z(10.0 * dt), atol=1e-9)
    assert np.allclose(truth[1].velocity, [10.0, 0, 0], atol=1e-6)


def test_scan_names_as_times(tmp_path):
    """MulRan's Ouster folder: each .bin named by its time in nanoseconds; poses (TUM)
    at 100 Hz are interpolated at those times."""
    d = tmp_path / "Ouster"
    d.mkdir()
    t0_ns = 1566000000123456789
    for k, dt_ns in enumerate((0, 100_000_000, 200_000_400)):
        write_bin(d / f"{t0_ns + dt_ns}.bin", np.full((10 + k, 4), float(k)))
    t0 = t0_ns * 1e-9
    (tmp_path / "tum.txt").write_text("".join("%.6f %.3f 0 0 0 0 0 1\n" % (t0 - 0.005 + 0.01 * i, 0.1 * i)
                                              for i in range(30)))    # 10 m/s along x
    out = tmp_path / "n.lcm"
    p = run([BIN / "import-scans", "--scans", d, "--poses", tmp_path / "tum.txt", "--times", "names", "--out", out])
    assert "times from the scans' names" in p.stderr, p.stderr
    scans, truth = scans_and_truth(out)
    assert [s.utime for s in scans] == [1566000000123457, 1566000000223457, 1566000000323457]
    assert [s.npoints for s in scans] == [10, 11, 12]
    for t in truth:
        assert abs(t.position[0] - 10.0 * ((t.utime * 1e-6 - t0) + 0.005)) < 2e-5   # microsecond stamps: 1e-5 m
    (d / "not_a_time.bin").write_bytes(b"")
    p = run([BIN / "import-scans", "--scans", d, "--poses", tmp_path / "tum.txt", "--times", "names", "--out", out],
            check=False)
    assert p.returncode == 1 and "not_a_time.bin: the name is not a time" in p.stderr, p.stderr


def test_poses_at_the_scan_instants_pair_by_index(tmp_path):
    """TUM poses whose times are the --times ones: scan k with pose k, as without --times."""
    make_bin_scans(tmp_path / "s", n=2)
    (tmp_path / "tum.txt").write_text("1700000000.25 1 2 3 0 0 0 1\n1700000000.35 4 5 6 0 0 0 1\n")
    (tmp_path / "times.txt").write_text("1700000000.2502\n1700000000.35\n")    # 0.2 ms apart: the same instant
    run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "tum.txt",
         "--times", tmp_path / "times.txt", "--out", tmp_path / "t.lcm"])
    _, truth = scans_and_truth(tmp_path / "t.lcm")
    assert [t.utime for t in truth] == [1700000000250200, 1700000000350000]
    assert np.allclose([t.position for t in truth], [[1, 2, 3], [4, 5, 6]])


def test_timed_poses_that_miss_every_scan_are_an_error(tmp_path):
    make_bin_scans(tmp_path / "s", n=2)
    (tmp_path / "tum.txt").write_text("1700000000.25 1 2 3 0 0 0 1\n1700000000.35 4 5 6 0 0 0 1\n")
    (tmp_path / "times.txt").write_text("1600000000.0\n1600000000.1\n")
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "tum.txt",
             "--times", tmp_path / "times.txt", "--out", tmp_path / "t.lcm"], check=False)
    assert p.returncode == 1
    assert "no scan time lies within the poses of" in p.stderr and "1600000000.000000" in p.stderr, p.stderr
    assert not (tmp_path / "t.lcm").exists()


def test_count_mismatch_imports_the_minimum_with_a_warning(tmp_path):
    make_bin_scans(tmp_path / "s", n=3)
    (tmp_path / "p.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 2)
    out = tmp_path / "m.lcm"
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "p.txt", "--out", out])
    assert "3 scans" in p.stderr and "2 poses" in p.stderr and "first 2" in p.stderr
    scans, truth = scans_and_truth(out)
    assert len(scans) == len(truth) == 2


@pytest.mark.parametrize("content, line, what", [
    ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n", 2, "expected 12 numbers"),
    ("1 0 0 0 0 1 0 0 0 0 1 0\n\n1 0 0 0 0 1 0 0 0 0 1 x\n", 3, "column 12"),
    ("1 0 0 0 0 1 0 0 0 0 1 0\n0 0 0 0 0 0 0 0\n", 2, "started as KITTI"),
    ("2 0 0 0 0 1 0 0 0 0 1 0\n", 1, "not a rotation"),
    ("1700000000 0 0 0 0 0 0 0\n", 1, "zero quaternion"),
    ("17000000000000000 1 2 3 0 0 0 1\n", 1, "bad time"),                  # 17 digits: no unit
    ("1700000000.2 1 2 3 0 0 0 1\n1700000000.1 1 2 3 0 0 0 1\n", 2, "not after"),
    ("1566000000000000000,1,0,0,0,0,1,0,0,0,0\n", 1, "expected 12 numbers"),     # commas, 11 numbers
])
def test_bad_pose_line_names_file_and_line(tmp_path, content, line, what):
    make_bin_scans(tmp_path / "s", n=2)
    poses = tmp_path / "bad.txt"
    poses.write_text(content)
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", poses, "--out", tmp_path / "x.lcm"],
            check=False)
    assert p.returncode == 1
    assert f"{poses}:{line}:" in p.stderr and what in p.stderr, p.stderr


def test_truncated_bin_names_byte_offset(tmp_path):
    make_bin_scans(tmp_path / "s", n=2)
    with open(tmp_path / "s" / "000001.bin", "ab") as f:
        f.write(b"\0" * 6)
    (tmp_path / "p.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 2)
    p = run([BIN / "import-scans", "--scans", tmp_path / "s", "--poses", tmp_path / "p.txt",
             "--out", tmp_path / "x.lcm"], check=False)
    assert p.returncode == 1
    assert "000001.bin: byte 816:" in p.stderr, p.stderr     # 51 points * 16 bytes
    scans, _ = scans_and_truth(tmp_path / "x.lcm")           # the scans before it are kept
    assert len(scans) == 1


def spinning_sweep(rings=16, cols=900, seam_deg=37.0, sweep_s=0.1, ccw=False):
    """A sweep of a spinning LiDAR in firing order (ring by ring, each turning from the seam):
    (n, 6) float32 x y z i ring t, t in seconds after the sweep's start. The ranges vary
    (a wall 12-18 m off), so neighbours in the file are neighbours in space."""
    turn = np.arange(cols) / cols
    az = np.radians(seam_deg) + (1 if ccw else -1) * 2 * np.pi * turn
    rows = []
    for r in range(rings):
        el = np.radians(-15 + 30 * r / (rings - 1))
        rng = 15 + 3 * np.sin(3 * az)
        rows.append(np.column_stack([rng * np.cos(el) * np.cos(az), rng * np.cos(el) * np.sin(az),
                                     rng * np.sin(el), np.full(cols, 10.0 + r), np.full(cols, r), turn * sweep_s]))
    return np.vstack(rows).astype("<f4")


def import_one(tmp_path, pts, *extra, check=True):
    d = tmp_path / "s"
    d.mkdir(exist_ok=True)
    write_bin(d / "000000.bin", pts)
    (tmp_path / "p.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    out = tmp_path / "x.lcm"
    p = run([BIN / "import-scans", "--scans", d, "--poses", tmp_path / "p.txt", "--out", out, *extra], check=check)
    return p, (scans_and_truth(out)[0] if p.returncode == 0 else None)


def test_bin_fields_give_rings_and_point_times(tmp_path):
    sweep = spinning_sweep()
    p, scans = import_one(tmp_path, sweep, "--bin-fields", "x,y,z,i,ring,t")
    s = scans[0]
    assert np.array_equal(scan_array(s), sweep[:, :4])
    assert np.array_equal(np.frombuffer(s.ring, np.uint8), sweep[:, 4].astype(np.uint8))
    assert np.array_equal(np.array(s.point_offset_us), np.round(sweep[:, 5].astype(float) * 1e6).astype(int))
    assert "no point times" not in p.stderr
    # a field skipped with _: no intensity, no ring (255), no times (0) and a note saying so
    p, scans = import_one(tmp_path, sweep, "--bin-fields", "x,y,z,_,_,_")
    assert np.array_equal(scan_array(scans[0])[:, :3], sweep[:, :3])
    assert set(scans[0].intensity) == {0.0} and set(scans[0].ring) == {255} and set(scans[0].point_offset_us) == {0}
    assert "1 scans have no point times: imported as motion-compensated" in p.stderr, p.stderr


def test_bin_of_another_point_size_is_an_error_naming_the_size(tmp_path):
    """nuScenes' .bin holds 5 floats a point; read 4 at a time, x y z come from other fields.
    With 900 points a ring the file is a multiple of 16 bytes, so only the points can tell."""
    sweep = spinning_sweep()[:, :5]
    p, _ = import_one(tmp_path, sweep, check=False)
    assert p.returncode == 1
    assert "000000.bin: read as 4 float32 a point" in p.stderr and "likely 5 floats each" in p.stderr, p.stderr
    assert "--bin-fields" in p.stderr
    _, scans = import_one(tmp_path, sweep, "--bin-fields", "x,y,z,i,ring")
    assert np.array_equal(scan_array(scans[0]), sweep[:, :4])
    # a cloud in no order (filtered, shuffled) is not judged: it imports as given
    shuffled = sweep[np.random.default_rng(3).permutation(len(sweep))][:, :4]
    _, scans = import_one(tmp_path, shuffled)
    assert scans[0].npoints == len(shuffled)


@pytest.mark.parametrize("ccw", [False, True])
def test_spin_gives_point_times_from_azimuth(tmp_path, ccw):
    """Raw sweeps without point times (x y z i): --spin takes each point's time from its
    azimuth, the sweep starting at the file's first point."""
    sweep = spinning_sweep(ccw=ccw)
    truth = np.round(sweep[:, 5].astype(float) * 1e6)
    p, scans = import_one(tmp_path, sweep[:, :4], "--spin", "ccw" if ccw else "cw")
    got = np.array(scans[0].point_offset_us, dtype=float)
    # within a microsecond but where float32 azimuths fall either side of the seam (a whole sweep)
    near = np.abs(got - truth) <= 1
    assert near.mean() > 0.99 and np.all(near | (np.abs(np.abs(got - truth) - 1e5) <= 1)), np.abs(got - truth).max()
    assert "no point times" not in p.stderr
    # the seam given: the same times; the other direction: an error naming it
    _, scans = import_one(tmp_path, sweep[:, :4], "--spin", "ccw" if ccw else "cw", "--seam-deg", "37")
    assert np.mean(np.abs(np.array(scans[0].point_offset_us) - truth) <= 1) > 0.99
    p, _ = import_one(tmp_path, sweep[:, :4], "--spin", "cw" if ccw else "ccw", check=False)
    assert p.returncode == 1
    assert f"points turn {'counter-clockwise' if ccw else 'clockwise'}" in p.stderr, p.stderr


def test_spin_needs_a_seam_for_points_in_no_order(tmp_path):
    sweep = spinning_sweep()
    shuffled = sweep[np.random.default_rng(5).permutation(len(sweep))]
    p, _ = import_one(tmp_path, shuffled[:, :4], "--spin", "cw", check=False)
    assert p.returncode == 1 and "not in firing order" in p.stderr and "--seam-deg" in p.stderr, p.stderr
    _, scans = import_one(tmp_path, shuffled[:, :4], "--spin", "cw", "--seam-deg", "37")
    got, truth = np.array(scans[0].point_offset_us), np.round(shuffled[:, 5].astype(float) * 1e6)
    assert np.mean(np.abs(got - truth) <= 1) > 0.99
    # point times of their own win over --spin, with a note
    p, scans = import_one(tmp_path, sweep, "--bin-fields", "x,y,z,i,ring,t", "--spin", "cw")
    assert np.array_equal(np.array(scans[0].point_offset_us), np.round(sweep[:, 5].astype(float) * 1e6))
    assert "1 scans carry point times of their own: --spin not used" in p.stderr


@pytest.mark.parametrize("fields,what", [("x,y,q", "'q' is not a field"), ("x,y,i", "x, y and z are needed"),
                                         ("x,y,z,x", "'x' twice")])
def test_bad_bin_fields(tmp_path, fields, what):
    p, _ = import_one(tmp_path, spinning_sweep()[:, :4], "--bin-fields", fields, check=False)
    assert p.returncode != 0 and what in p.stderr, p.stderr


def test_bin_point_time_beyond_a_sweep_names_its_byte(tmp_path):
    sweep = spinning_sweep()
    sweep[20, 5] = 1.6e9     # an absolute time cannot be held by a float32 to the microsecond
    p, _ = import_one(tmp_path, sweep, "--bin-fields", "x,y,z,i,ring,t", check=False)
    assert p.returncode == 1
    assert f"000000.bin: byte {20 * 24 + 20}: point time 1.6e+09 s" in p.stderr, p.stderr


# ---------------------------------------------------------------- build-map

def write_mapping_log(path, vehicle_lidar=None, extra_scan_times=()):
    """A straight drive at 10 m/s past a wall at x = WALL_X; LIDAR_SCAN in
    point form with per-point offsets over a 100 ms sweep. The lidar points are
    computed from the exact pose at each point's time, so a correct de-skew puts
    every point back on the world geometry."""
    import lcm
    log = lcm.EventLog(str(path), "w", overwrite=True)
    bl = np.zeros(3) if vehicle_lidar is None else np.asarray(vehicle_lidar, dtype=float)
    yaw_rate = 0.1  # rad/s: orientation changes too, so slerp is exercised

    def base_pose(t_us):
        s = (t_us - T0) * 1e-6
        return np.array([10.0 * s, 0.5 * s, 0.0]), yaw_rate * s

    rng = np.random.default_rng(3)
    world = np.column_stack([np.full(2000, WALL_X), rng.uniform(-10, 10, 2000), rng.uniform(0, 5, 2000)])
    for i in range(0, 121):  # poses at 100 Hz for 1.2 s
        t = T0 + i * 10_000
        pos, yaw = base_pose(t)
        p = portobello.pose_t()
        p.utime = t
        p.position = list(pos)
        p.orientation = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        p.velocity = [10.0, 0.5, 0.0]
        p.angular_velocity = [0.0, 0.0, yaw_rate]
        p.covariance = [0.0] * 36
        p.status = p.STATUS_TRACKING
        p.source = p.SOURCE_GROUND_TRUTH
        p.match_score = float("nan")
        log.write_event(t, "GROUND_TRUTH", p.encode())
    scan_times = [T0 + k * 100_000 for k in range(11)] + list(extra_scan_times)
    for k, ts in enumerate(scan_times):
        offs = np.sort(rng.integers(0, 100_000, len(world))).astype(np.int32)
        pts = np.empty((len(world), 3))
        for j, (w, o) in enumerate(zip(world, offs)):
            pos, yaw = base_pose(ts + int(o))
            R = rot_z(math.degrees(yaw))
            pts[j] = R.T @ (w - pos) - bl          # lidar axes = base axes, offset bl
        s = portobello.lidar_scan_t()
        s.utime = ts
        s.sensor = "test"
        s.seq = k
        s.lidar_from_beam = list(np.eye(4).ravel())
        s.npoints = len(world)
        s.x, s.y, s.z = (list(pts[:, a].astype(np.float32)) for a in range(3))
        s.intensity = [float(k)] * len(world)
        s.point_offset_us = [int(o) for o in offs]
        s.ring = [255] * len(world)
        log.write_event(ts, "LIDAR_SCAN", s.encode())
    log.close()
    return world


def test_build_map_deskews_with_per_point_poses(tmp_path):
    log = tmp_path / "drive.lcm"
    # scans at 0..1.0 s sweep 100 ms inside the poses (0..1.2 s); one at 1.15 s runs past them
    world = write_mapping_log(log, extra_scan_times=[T0 + 1_150_000])
    out = tmp_path / "map.pcd"
    p = run([BIN / "build-map", "--log", log, "--out", out, "--voxel", "0"])
    assert "1 scans skipped" in p.stderr, p.stderr
    assert "11 of 12 scans used" in p.stderr, p.stderr
    _, m = read_pcd(out)
    assert len(m) == 11 * len(world)
    # voxel 0 keeps every point in order: scan by scan, each the same 2000 world points
    err = np.abs(m[:, :3].astype(np.float64) - np.tile(world, (11, 1))).max()
    assert err < 1e-4, err


def test_build_map_with_vehicle_extrinsics_and_voxels(tmp_path):
    import yaml
    veh = yaml.safe_load((ROOT / "vehicles" / "prius2017.yaml").read_text())
    lidar_xyz = veh["sensors"]["lidar"]["xyz"]
    log = tmp_path / "drive.lcm"
    world = write_mapping_log(log, vehicle_lidar=lidar_xyz)
    out = tmp_path / "map.pcd"
    run([BIN / "build-map", "--log", log, "--out", out, "--vehicle", ROOT / "vehicles" / "prius2017.yaml",
         "--voxel", "0.15", "--every", "2"])
    _, m = read_pcd(out)
    assert np.abs(m[:, 0] - WALL_X).max() < 2e-3     # the wall, in map
    n_vox = len(voxel_keys(world, 0.15))
    assert abs(len(m) - n_vox) <= 3                  # one point per occupied voxel
    assert np.allclose(m[:, 3], 5.0, atol=1e-4)     # mean intensity of scans 0, 2, ..., 10 (--every 2)
    # without --vehicle the lidar offset is not applied: the wall moves by the lever arm
    out2 = tmp_path / "map2.pcd"
    run([BIN / "build-map", "--log", log, "--out", out2, "--voxel", "0.15"])
    _, m2 = read_pcd(out2)
    assert abs(np.median(m2[:, 0]) - (WALL_X - lidar_xyz[0])) < 0.05


def test_build_map_help_and_errors(tmp_path):
    assert "--pose-channel" in run([BIN / "build-map", "--help"]).stdout
    assert "--map-out" in run([BIN / "import-scans", "--help"]).stdout
    log = tmp_path / "empty.lcm"
    import lcm
    lcm.EventLog(str(log), "w", overwrite=True).close()
    p = run([BIN / "build-map", "--log", log, "--out", tmp_path / "m.pcd"], check=False)
    assert p.returncode == 1 and "no GROUND_TRUTH poses" in p.stderr


# ---------------------------------------------------------------- real data (make test-real)

RAV4 = SHARED_DATA / "can_rav4_comma2k19"
MULRAN = SHARED_DATA / "lidar_seq_mulran_riverside02_part1"


def need(path):
    if not path.exists():
        pytest.skip(f"{path} is absent (real data lives in ../shared/data)")


@pytest.mark.real
def test_real_rav4_full_log_and_wheel_speeds(tmp_path):
    need(RAV4)
    import cantools
    src = RAV4 / "rav4_2018-08-02_seg40.candump.log"
    out = tmp_path / "rav4.lcm"
    run([BIN / "import-candump", "--in", src, "--out", out, "--quiet"])
    lines = src.read_text().splitlines()
    frames = can_frames(out)
    assert len(frames) == len(lines) == 135468
    for f, line in zip(frames, lines):
        assert (f.utime, f.bus, f.id, bytes(f.data)) == parse_candump_line(line)
    db = cantools.database.load_file(str(ROOT / "vehicles" / "dbc" / "toyota_prius_2017_pt_generated.dbc"))
    ws = [f for f in frames if f.bus == 0 and f.id == 0x0AA]
    ref = np.genfromtxt(RAV4 / "can_speed_wheelspeeds_mps.csv", delimiter=",", names=True)
    assert len(ws) == len(ref) == 4974
    worst = 0.0
    for f, r in zip(ws, ref):
        assert f.utime == round(r["t_unix"] * 1e6)
        d = db.decode_message(0x0AA, bytes(f.data))
        for sig, col in (("WHEEL_SPEED_FL", "ws_fl_mps"), ("WHEEL_SPEED_FR", "ws_fr_mps"),
                         ("WHEEL_SPEED_RL", "ws_rl_mps"), ("WHEEL_SPEED_RR", "ws_rr_mps")):
            worst = max(worst, abs(d[sig] - r[col] * 3.6))
    assert worst < 0.01, worst


@pytest.mark.real
def test_real_mulran_every_other_scan_with_map(tmp_path):
    """MulRan Riverside02 keyframes (FAST-LIO2 estimates, not ground truth). The
    full 332-scan export has 331 poses; this part holds 166/166/166, so the
    mismatch path is exercised by dropping the last pose line."""
    need(MULRAN)
    scans_dir = MULRAN / "Scans"
    files = sorted(os.listdir(scans_dir))
    poses = np.loadtxt(MULRAN / "odom_poses.txt")
    times = (MULRAN / "times.txt").read_text().split()
    out, site = tmp_path / "mulran.lcm", tmp_path / "site"
    p = run([BIN / "import-scans", "--scans", scans_dir, "--poses", MULRAN / "odom_poses.txt",
             "--times", MULRAN / "times.txt", "--out", out, "--every", "2",
             "--map-out", site / "map.pcd", "--voxel", "0.5"])
    assert "warning" not in p.stderr, p.stderr
    scans, truth = scans_and_truth(out)
    n = min(len(files), len(poses), len(times))
    idx = list(range(0, n, 2))
    assert len(scans) == len(truth) == len(idx) == 83
    for j in (0, len(idx) - 1):
        k = idx[j]
        _, ref = read_pcd(scans_dir / files[k])
        got = scan_array(scans[j])
        assert scans[j].npoints == len(ref)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[-1], ref[-1])
        P = poses[k].reshape(3, 4)
        assert np.allclose(truth[j].position, P[:, 3], atol=1e-9)
        assert np.allclose(matrix_from_quat(truth[j].orientation), P[:, :3], atol=1e-4)
        sec, frac = times[k].split(".")
        assert truth[j].utime == int(sec) * 1_000_000 + (int(frac.ljust(7, "0")[:7]) + 5) // 10
    assert sorted(os.listdir(site)) == ["map.pcd"]
    _, m = read_pcd(site / "map.pcd")
    assert len(voxel_keys(m, 0.5)) >= len(m) - len(m) // 1000
    assert 10_000 < len(m) < sum(s.npoints for s in scans)
    # the 331-poses-for-332-scans case: one pose fewer than scans
    short = tmp_path / "short.txt"
    short.write_text("".join((MULRAN / "odom_poses.txt").read_text().splitlines(keepends=True)[:-1]))
    p = run([BIN / "import-scans", "--scans", scans_dir, "--poses", short, "--times", MULRAN / "times.txt",
             "--out", tmp_path / "short.lcm"])
    assert f"{len(files)} scans" in p.stderr and f"{len(poses) - 1} poses" in p.stderr
    s2, _ = scans_and_truth(tmp_path / "short.lcm")
    assert len(s2) == len(poses) - 1
