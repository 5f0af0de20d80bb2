#!/usr/bin/env bash
# make demo: the main job on the default site. Simulates a 60 s drive (LiDAR, IMU,
# CAN, GNSS, ground truth), replays it through the replay driver and summarises it,
# then runs the crosswalk study on the lab twin and on the road car, prints the
# two SCENARIO_EVENT sequences side by side and makes the study report of both.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/demo}
mkdir -p "$out"
echo "== 1. simulate a 60 s drive on maps/default (seed 7, normal speed profile)"
build/bin/simdrive --seed 7 --duration 60 --speed-profile normal --out "$out"
echo
echo "== 2. replay it through log-summary (as fast as the CPU allows, time from the log)"
build/bin/log-summary --replay "$out/drive.lcm" --out "$out/summary.lcm"
echo
echo "== 3. what was written"
ls -l "$out/drive.lcm" "$out/ground_truth.tum" "$out/summary.lcm"
echo
echo "== 4. the crosswalk study on both platforms (lab twin and road car, same scenario files)"
bash tools/demo-study.sh "$out/study"
echo
echo "== 5. the study report of those two sessions (decisions, collisions, timing; docs/study_report.md)"
bash tools/demo-study-report.sh "$out/study"
echo
echo "Replay it on the live bus:   .venv/bin/lcm-logplayer --lcm-url='udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608' $out/drive.lcm"
echo "and watch it:                build/bin/log-summary   (Ctrl-C prints the summary)"
echo
echo "The pages (webui bridge; docs/webui.md):  build/bin/webui --site maps/default   then open"
echo "  http://127.0.0.1:8080/operator   http://127.0.0.1:8080/participant   http://127.0.0.1:8080/editor   http://127.0.0.1:8080/view"
