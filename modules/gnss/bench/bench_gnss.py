"""make bench-gnss: parse throughput of the gnss core vs pyubx2 on the same bytes.

Input: every clean capture in tests/data/ublox (UBX, UBX+NMEA, pure NMEA; no bad
checksums), concatenated and repeated to --mb megabytes. Both parsers see the same
buffer in the same run. Baselines (PyPI pyubx2 1.4.0, the maintained Python UBX/NMEA
parser):
  pyubx2 same work : UBXReader(parsing=False) framing, then pyubx2.isvalid_checksum on
                     every UBX frame, UBXReader.parse of NAV-PVT, pynmeagps parse of
                     GGA/RMC/GST and an XOR check of other NMEA: the work the C core does
  pyubx2 parse all : UBXReader(parsing=True): checksums and every field of every message
The gnss core frames every message and checksums it, decodes NAV-PVT, GGA and RMC and
builds fixes (it skips the fields of other message types). Medians over --runs runs of
process CPU time (wall time on the shared 2-core machine mostly measures the neighbours).
"""
import argparse
import io
import json
import pathlib
import statistics
import subprocess
import time

ROOT = pathlib.Path(__file__).resolve().parents[3]

CLEAN = ["pygpsdata-MIXED.log", "pygpsdata-MIXED3.log", "pygpsdata-NAV.log", "pygpsdata-ESF.log",
         "pygpsdata-HNR.log", "pygpsdata-SF-calibration.log", "ublox-zed-f9p-nmea.stripped.nmea"]


def pyubx2_pass(buf, parse_all):
    import pynmeagps
    import pyubx2
    r = pyubx2.UBXReader(io.BytesIO(buf), protfilter=pyubx2.NMEA_PROTOCOL | pyubx2.UBX_PROTOCOL | pyubx2.RTCM3_PROTOCOL,
                         quitonerror=pyubx2.ERR_IGNORE, parsing=parse_all)
    n = 0
    t0 = time.process_time()
    for raw, parsed in r:
        n += 1
        if parse_all:
            continue
        if raw[0] == 0xB5:
            if pyubx2.isvalid_checksum(raw) and raw[2] == 0x01 and raw[3] == 0x07:
                pyubx2.UBXReader.parse(raw)
        elif raw[0] == 0x24:
            if raw[3:6] in (b"GGA", b"RMC", b"GST"):
                pynmeagps.NMEAReader.parse(raw)
            else:
                star = raw.rfind(b"*")
                ck = 0
                for c in raw[1:star]:
                    ck ^= c
                assert ck == int(raw[star + 1:star + 3], 16)
    return time.process_time() - t0, n


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--mb", type=float, default=0.6)
    ap.add_argument("--runs", type=int, default=21)
    ap.add_argument("--py-runs", type=int, default=3)
    ap.add_argument("--py-all-runs", type=int, default=1, help="runs of the (slow) parse-all baseline")
    a = ap.parse_args()
    files = [pathlib.Path(a.data) / f for f in CLEAN]
    one = b"".join(f.read_bytes() for f in files)
    target = int(a.mb * 1e6)
    reps = -(-target // len(one))
    buf = one * reps
    tmp = pathlib.Path("build/bench")
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / "gnss_input.bin").write_bytes(buf)

    out = subprocess.run([a.bin, "--runs", str(a.runs), "--repeat-to", str(len(buf)), str(tmp / "gnss_input.bin")],
                         check=True, capture_output=True, text=True).stdout
    c = json.loads(out)
    rows = [("gnss core (C, this project)", statistics.median(c["seconds"]), c["frames"], len(c["seconds"]))]
    # the baseline is part of the environment (tools/requirements.txt): without it the bench fails
    for label, parse_all in (("pyubx2 1.4.0 same work (baseline)", False),
                             ("pyubx2 1.4.0 parse all (baseline)", True)):
        res = [pyubx2_pass(buf, parse_all) for _ in range(a.py_all_runs if parse_all else a.py_runs)]
        rows.append((label, statistics.median(t for t, _ in res), res[0][1], len(res)))

    nbytes = len(buf)
    print(f"bench-gnss: {nbytes / 1e6:.2f} MB = {reps} x {len(one)} B of the clean captures in tests/data/ublox "
          f"({len(CLEAN)} files: UBX, UBX+NMEA, NMEA)")
    print(f"{'parser':38s} {'runs':>4s} {'median CPU s':>12s} {'MB/s':>8s} {'messages':>9s} {'msg/s':>11s} {'vs C':>8s}")
    base = rows[0][1]
    for label, t, n, runs in rows:
        print(f"{label:38s} {runs:4d} {t:12.4f} {nbytes / 1e6 / t:8.2f} {n:9d} {n / t:11.0f} {t / base:7.1f}x")
    print(f"C fixes built: {c['ubx_nav_pvt_fixes']}, errors: {c['errors']} "
          "(messages: C counts UBX + NMEA + RTCM3 frames; pyubx2 counts what its reader returns)")
    out = ROOT / "build" / "bench" / "gnss.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"bytes": nbytes, "rows": [
        {"parser": label, "runs": runs, "median_cpu_s": t, "mb_per_s": nbytes / 1e6 / t, "messages": n,
         "x_slower_than_c": t / base} for label, t, n, runs in rows]}, indent=1))
    print(f"written: {out}")


if __name__ == "__main__":
    main()
