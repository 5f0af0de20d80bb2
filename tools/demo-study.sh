#!/usr/bin/env bash
# The default site's crosswalk study on both platforms, as each runs in practice:
#   lab:  the twin (lab_vehicle, offline, proceed pressed 2 s after each stop);
#   road: a simulated drive (simdrive: LiDAR, IMU, CAN, GNSS) through the road
#         pipeline: can (CAN_FRAME -> VEHICLE_SPEED), log-merge, localizer (POSE in
#         the prior map, started from GNSS alone).
# The director runs every scenario of maps/default/scenarios/ on both drives,
# unchanged, and the two SCENARIO_EVENT sequences are printed side by side.
# Exit 1 if any pair differs.
#   tools/demo-study.sh [OUT_DIR]     (default build/demo-study; SITE=... for another site)
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/script-args.sh" options -- "$@"
cd "$(dirname "$0")/.."
out=${1:-build/demo-study}
site=${SITE:-maps/default}
mkdir -p "$out"
echo "== lab: lab_vehicle drives 90 s of $site (normal profile), proceed 2.0 s after each stop"
build/bin/lab_vehicle --site "$site" --out "$out/lab.lcm" --auto-proceed 2.0 --duration 90
echo "== road: simdrive drives 90 s of $site (seed 7, normal profile)"
build/bin/simdrive --site "$site" --seed 7 --duration 90 --quiet --out "$out/road"
echo "== road: can decodes CAN_FRAME to VEHICLE_SPEED; the localizer places the car in $site/map.pcd"
build/bin/can --replay "$out/road/drive.lcm" --out "$out/road/speed.lcm" 2>/dev/null
build/bin/log-merge --quiet --out "$out/road/sensors.lcm" "$out/road/drive.lcm" "$out/road/speed.lcm"
build/bin/localizer --site "$site" --replay "$out/road/sensors.lcm" --out "$out/road/localizer.lcm"
.venv/bin/python - "$out/road/drive.lcm" "$out/road/localizer.lcm" <<'PY'
import sys, bisect, math
sys.path.insert(0, "build/python")
import lcm
import portobello
gt, est = [], []
for ev in lcm.EventLog(sys.argv[1], "r"):
    if ev.channel == "GROUND_TRUTH":
        p = portobello.pose_t.decode(ev.data); gt.append((p.utime, p.position[0], p.position[1]))
for ev in lcm.EventLog(sys.argv[2], "r"):
    if ev.channel == "POSE":
        p = portobello.pose_t.decode(ev.data)
        if p.status == portobello.pose_t.STATUS_TRACKING: est.append((p.utime, p.position[0], p.position[1]))
ts = [g[0] for g in gt]
err = []
for t, x, y in est:
    i = bisect.bisect_left(ts, t)
    if 0 < i < len(gt):
        (t0, x0, y0), (t1, x1, y1) = gt[i - 1], gt[i]
        a = (t - t0) / (t1 - t0)
        err.append(math.hypot(x - (x0 + a * (x1 - x0)), y - (y0 + a * (y1 - y0))))
err.sort()
print(f"   localizer vs ground truth: {len(err)} tracking poses, horizontal error median "
      f"{err[len(err) // 2]:.3f} m, p99 {err[int(0.99 * (len(err) - 1))]:.3f} m")
PY
echo "== check: build/bin/scenario-check --site $site"
build/bin/scenario-check --site "$site"
status=0
for f in "$site"/scenarios/*.yaml; do
    name=$(basename "$f" .yaml)
    build/bin/director --site "$site" --scenario "$f" --replay "$out/lab.lcm" --out "$out/lab_$name.lcm" 2>/dev/null
    build/bin/director --site "$site" --scenario "$f" \
        --replay "$out/road/localizer.lcm" --out "$out/road_$name.lcm" 2>/dev/null
    echo
    echo "== $name: SCENARIO_EVENT, lab (POSE from lab_vehicle) | road (POSE from the localizer); s since the drive's start"
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
