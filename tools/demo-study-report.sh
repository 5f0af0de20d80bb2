#!/usr/bin/env bash
# make demo, last step: the study report of the demo's two sessions, one participant
# "demo", lab first. The lab session is the twin's drive merged with the director's
# output; the road session is the supervised stack's recording (every channel of the
# live bus, possibly split into several files by size).
#   tools/demo-study-report.sh OUT_DIR LAB_LOG... -- ROAD_RECORDING...
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/script-args.sh" options -- "$@"
cd "$(dirname "$0")/.."
out=$1; shift
site=${SITE:-maps/default}
lab=(); road=()
while [ $# -gt 0 ] && [ "$1" != "--" ]; do lab+=("$1"); shift; done
[ $# -gt 0 ] && shift
road=("$@")
[ ${#lab[@]} -gt 0 ] && [ ${#road[@]} -gt 0 ] || { echo "usage: $0 OUT_DIR LAB_LOG... -- ROAD_RECORDING..." >&2; exit 2; }
study="$out/study"
mkdir -p "$study"
build/bin/log-merge --quiet --out "$study/lab.lcm" "${lab[@]}"
build/bin/log-merge --quiet --out "$study/road.lcm" "${road[@]}"
printf 'participant,order,platform,recording\ndemo,lab_first,lab,lab.lcm\ndemo,lab_first,road,road.lcm\n' > "$study/study.csv"
# The demo has no questionnaire: one participant's example ratings (a Bayes factor needs
# at least two participants, so the table says "too few pairs").
printf 'participant,platform,measure,value\ndemo,lab,realism,3\ndemo,road,realism,4\ndemo,lab,presence,3\ndemo,road,presence,5\n' \
    > "$study/questionnaire.csv"
build/bin/study-report --site "$site" --questionnaire "$study/questionnaire.csv" --sessions "$study" \
    --out "$out/report" --json "$out/report/report.json" --title "make demo: the crosswalk study, lab twin and road car"
echo "   decisions per encounter: $out/report/encounters.csv"
echo "   open $out/report/report.html"
