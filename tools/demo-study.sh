#!/usr/bin/env bash
# The default site's crosswalk study on both platforms: the lab twin (lab_vehicle,
# offline, proceed pressed 2 s after each stop) and the road car (simdrive ground
# truth) each drive past the four crosswalks; the director runs every scenario of
# maps/default/scenarios/ on both drives, unchanged, and the two SCENARIO_EVENT
# sequences are printed side by side. Exit 1 if any pair differs.
#   tools/demo-study.sh [OUT_DIR]     (default build/demo-study; SITE=... for another site)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/demo-study}
site=${SITE:-maps/default}
mkdir -p "$out"
echo "== lab: lab_vehicle drives 90 s of $site (normal profile), proceed 2.0 s after each stop"
build/bin/lab_vehicle --site "$site" --out "$out/lab.lcm" --auto-proceed 2.0 --duration 90
echo "== road: simdrive drives 90 s of $site (seed 7, normal profile, no LiDAR)"
build/bin/simdrive --site "$site" --seed 7 --duration 90 --no-lidar --quiet --out "$out/road"
echo "== check: build/bin/scenario-check --site $site"
build/bin/scenario-check --site "$site"
status=0
for f in "$site"/scenarios/*.yaml; do
    name=$(basename "$f" .yaml)
    build/bin/director --site "$site" --scenario "$f" --replay "$out/lab.lcm" --out "$out/lab_$name.lcm" 2>/dev/null
    build/bin/director --site "$site" --scenario "$f" --pose-channel GROUND_TRUTH \
        --replay "$out/road/drive.lcm" --out "$out/road_$name.lcm" 2>/dev/null
    echo
    echo "== $name: SCENARIO_EVENT, lab (POSE from lab_vehicle) | road (GROUND_TRUTH from simdrive); s since the drive's start"
    .venv/bin/python - "$out/lab_$name.lcm" "$out/road_$name.lcm" <<'PY' || status=1
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
t0 = 1714572000000000   # both drives start at the same fixed epoch
w = 48
for i in range(max(len(lab), len(road))):
    cell = lambda s: f"{(s[i][0] - t0) * 1e-6:7.2f} {s[i][1]:<9} {s[i][2]}"[:w] if i < len(s) else ""
    print(f"  {cell(lab):<{w}} | {cell(road)}")
same = [e[1:] for e in lab] == [e[1:] for e in road]
print(f"  {len(lab)} lab events, {len(road)} road events: sequences {'IDENTICAL' if same else 'DIFFER'}")
sys.exit(0 if same else 1)
PY
done
echo
echo "Timing of the synchronised pedestrians and the cost per pose: make bench-director"
exit $status
