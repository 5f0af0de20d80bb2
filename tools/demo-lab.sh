#!/usr/bin/env bash
# The crosswalk study on both platforms: the in-lab twin (lab_vehicle, offline) and
# the road car (simdrive), each run through the director with the same scenario
# file, and the two SCENARIO_EVENT sequences printed side by side.
#   tools/demo-lab.sh [OUT_DIR] [SCENARIO]     (default build/demo-lab, cw01_look_and_cross)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/demo-lab}
scenario=${2:-cw01_look_and_cross}
site=${SITE:-maps/default}
director=${DIRECTOR:-build/bin/director}
mkdir -p "$out"
echo "== 1. lab: the twin drives one lap of $site, proceed pressed 2.0 s after each stop"
build/bin/lab_vehicle --site "$site" --out "$out/lab.lcm" --auto-proceed 2.0
echo
echo "== 2. road: simdrive drives the same route (seed 7, 300 s, no LiDAR needed here)"
build/bin/simdrive --site "$site" --seed 7 --duration 300 --no-lidar --quiet --out "$out/road"
echo
if [[ ! -x "$director" ]]; then
    echo "== 3. (no $director: the scenario step needs modules/director)"
    exit 0
fi
echo "== 3. the director runs scenario $scenario on both drives (replay, time from the logs)"
"$director" --site "$site" --scenario "$scenario" --replay "$out/lab.lcm" --out "$out/lab_director.lcm"
"$director" --site "$site" --scenario "$scenario" --pose-channel GROUND_TRUTH \
    --replay "$out/road/drive.lcm" --out "$out/road_director.lcm"
echo
echo "== 4. SCENARIO_EVENT on both platforms (time since the start of each drive)"
.venv/bin/python - "$out/lab_director.lcm" "$out/road_director.lcm" <<'PY'
import sys
sys.path.insert(0, "build/python")
import lcm
import portobello

def events(path):
    out = []
    for ev in lcm.EventLog(path, "r"):
        if ev.channel == "SCENARIO_EVENT":
            e = portobello.scenario_event_t.decode(ev.data)
            out.append((e.utime, e.kind, e.event_id, e.agent_id))
    return out

lab, road = events(sys.argv[1]), events(sys.argv[2])
t0 = 1714572000000000   # both drives start at lab_vehicle's and simdrive's fixed epoch
w = 44
print(f"{'lab (lab_vehicle)':<{w}} | road (simdrive)")
for i in range(max(len(lab), len(road))):
    cell = lambda s: f"{(s[i][0] - t0) * 1e-6:7.2f} s {s[i][1]:<9} {s[i][2]}"[:w] if i < len(s) else ""
    print(f"{cell(lab):<{w}} | {cell(road)}")
same = [e[1:] for e in lab] == [e[1:] for e in road]
print(f"\n{len(lab)} lab events, {len(road)} road events: sequences {'IDENTICAL' if same else 'DIFFER'}")
sys.exit(0 if same else 1)
PY
