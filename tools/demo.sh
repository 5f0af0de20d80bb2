#!/usr/bin/env bash
# make demo: the main job on the default site. The crosswalk study runs once on the lab
# twin and once on a simulated road drive played in real time through the supervised live
# stack (stacks/replay.yaml: lcm-logplayer, can, localizer, director, the session
# recorder); then a report, as text and as one HTML page, compares the two, and the
# study report (docs/study_report.md) codes both sessions.
#   tools/demo.sh [OUT_DIR]      (default build/demo)
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/script-args.sh" options -- "$@"
cd "$(dirname "$0")/.."
out=${1:-build/demo}
site=maps/default
start=$(date +%s)
mkdir -p "$out"
# The demo's own bus: a port derived from this checkout's path, so two checkouts on one
# machine do not hear each other (LCM_DEFAULT_URL overrides it).
port=$((7600 + $(pwd | cksum | cut -d' ' -f1) % 100))
export LCM_DEFAULT_URL=${LCM_DEFAULT_URL:-"udpm://239.255.76.67:$port?ttl=0&recv_buf_size=8388608"}

echo "== 1. simulate a 90 s drive on $site (seed 7, normal speed profile): LiDAR, IMU, CAN, GNSS, ground truth"
build/bin/simdrive --seed 7 --duration 90 --speed-profile normal --quiet --out "$out"
echo
echo "== 2. what the drive holds (log-summary replays it as fast as the CPU allows, time from the log)"
build/bin/log-summary --replay "$out/drive.lcm" --out "$out/summary.lcm"
echo
echo "== 3. lab: the twin drives 90 s of $site, proceed pressed 2 s after each stop; the director runs the study"
mkdir -p "$out/lab"
build/bin/lab_vehicle --site "$site" --out "$out/lab/drive.lcm" --auto-proceed 2.0 --duration 90 --quiet
build/bin/director --site "$site" --scenario crosswalk_study --replay "$out/lab/drive.lcm" \
    --out "$out/lab/director.lcm" 2>/dev/null
echo
echo "== 4. road: $out/drive.lcm played in real time by lcm-logplayer through the supervised live stack"
echo "   build/bin/supervisor --config stacks/replay.yaml (bus $LCM_DEFAULT_URL)"
rm -rf "$out/live"
mkdir -p "$out/live"
build/bin/supervisor --config stacks/replay.yaml --set LOG="$out/drive.lcm" --set RUN_DIR="$out/live" \
    2> "$out/live/supervisor.log" &
sup=$!
trap 'kill -TERM $sup 2>/dev/null || true; wait $sup 2>/dev/null || true' EXIT
# Until the player has played the whole log (state EXITED); the state every 20 s.
deadline=$((SECONDS + 600)); next=0
while :; do
    state=$(build/bin/supervisorctl --stack replay --timeout 3 list 2>/dev/null || true)
    if [ $SECONDS -ge $next ] && [ -n "$state" ]; then echo "$state" | sed 's/^/   /'; next=$((SECONDS + 20)); fi
    echo "$state" | grep -Eq '^player +player +EXITED' && break
    echo "$state" | grep -Eq '^player +player +FAILED' && { echo "demo: the player FAILED" >&2; exit 1; }
    [ $SECONDS -lt $deadline ] || { echo "demo: the live replay did not finish in 600 s" >&2; exit 1; }
    sleep 2
done
sleep 1.5    # the last messages reach the recorder
build/bin/supervisorctl --stack replay list | sed 's/^/   /'
kill -TERM $sup
wait $sup
trap - EXIT
echo "   recorded: $(ls "$out"/live/recordings/)"
echo
echo "== 5. the report"
.venv/bin/python tools/demo-report/report.py --site "$site" --lab "$out/lab/drive.lcm" "$out/lab/director.lcm" \
    --road "$out"/live/recordings/P00_S1.lcm.* --out "$out/report" > /dev/null
sed -n '4,$p' "$out/report/report.txt"
echo
echo "== 6. the study report of those two sessions (decisions, collisions, timing; docs/study_report.md)"
bash tools/demo-study-report.sh "$out/study" "$out/lab/drive.lcm" "$out/lab/director.lcm" -- "$out"/live/recordings/P00_S1.lcm.*
echo
echo "The pages (webui bridge; docs/webui.md):  build/bin/webui --site maps/default   then open"
echo "  http://127.0.0.1:8080/operator   http://127.0.0.1:8080/participant   http://127.0.0.1:8080/editor   http://127.0.0.1:8080/view"
echo
echo "make demo took $(($(date +%s) - start)) s. Replay the recording: docs/recording.md"
echo "The report: $out/report/report.html (and report.txt)"
