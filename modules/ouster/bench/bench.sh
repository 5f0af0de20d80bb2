#!/usr/bin/env bash
# make bench-ouster: CPU cost of decoding a 64 x 1024 @ 10 Hz Ouster stream (the OS1-64
# capture in tests/data/ouster, one frame's 64 packets replayed FRAMES times), next to
# two baselines measured in the same run on the same packets: a raw copy of the packets,
# and ouster-sdk 1.0.1 (PyPI; installed into build/bench/ouster-sdk-venv on first use).
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/../../../tools/script-args.sh" none -- "$@"
cd "$(dirname "$0")/../../.."
FRAMES=${FRAMES:-300}
PCAP=tests/data/ouster/OS-1-64_1024x10_fw20.pcap
META=tests/data/ouster/OS-1-64_sensor_config_reduced.json
VENV=build/bench/ouster-sdk-venv
if [ ! -x $VENV/bin/python ] || ! $VENV/bin/python -c 'import ouster.sdk' 2>/dev/null; then
  echo "bench-ouster: installing ouster-sdk==1.0.1 into $VENV (baseline only)..." >&2
  mkdir -p build/bench
  { python3 -m venv $VENV && $VENV/bin/pip install -q --disable-pip-version-check ouster-sdk==1.0.1; } >&2 || {
    echo "bench-ouster: ouster-sdk==1.0.1 did not install into $VENV (PyPI must be reachable): no baseline, no table" >&2
    exit 1; }
fi
ours=$(build/bin/ouster-bench --pcap $PCAP --metadata $META --frames "$FRAMES")
sdk=$($VENV/bin/python modules/ouster/bench/sdk_baseline.py $PCAP $META "$FRAMES")
python3 - "$ours" "$sdk" <<'PY'
import json, sys
o, s = json.loads(sys.argv[1]), json.loads(sys.argv[2])
hz = o["frame_rate_hz"]
rows = [("raw copy of the frame's packets (memcpy)", o["copy_us"])]
rows.append(("ouster-sdk 1.0.1 FrameBatcher, from Python", s["sdk_batch_us"]))
rows += [("ouster driver: decode + frame assembly", o["decode_us"]),
         ("ouster driver: decode + LCM encode of LIDAR_SCAN", o["decode_encode_us"])]
print(f"Ouster decoding, {o['sensor']} {o['profile']} {o['rows']}x{o['cols']} @ {hz} Hz "
      f"({o['packets_per_frame']} packets/frame, {o['frames']} frames, median thread CPU time; "
      f"LIDAR_SCAN {o['scan_bytes']} bytes)")
print(f"| {'what':50} | {'us/frame':>9} | {'% of a core':>11} | {'vs decode':>9} |")
print(f"|{'-'*52}|{'-'*11}|{'-'*13}|{'-'*11}|")
for name, us in rows:
    print(f"| {name:50} | {us:9.1f} | {us * hz / 1e4:10.2f}% | {us / o['decode_us']:8.2f}x |")
share = o["decode_encode_us"] * hz / 1e4
print(f"target: <= 5% of a core -> {'met' if share <= 5 else 'NOT met'} ({share:.2f}% with encoding)")
with open("build/bench/ouster.json", "w") as f:
    json.dump({"ours": o, "sdk": s, "rows": [{"what": n, "us_per_frame": us} for n, us in rows],
               "core_share_pct": share, "target_pct": 5}, f, indent=1)
print("written: build/bench/ouster.json")
PY
