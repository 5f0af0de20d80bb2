#!/usr/bin/env bash
# make demo, last step: the study report for the demo's two sessions (the lab twin and
# the road car of tools/demo-study.sh, one participant "demo", lab first). Each
# recording is the vehicle's log merged with one scenario's director output.
#   tools/demo-study-report.sh [STUDY_OUT_DIR]   (default build/demo-study; the folder demo-study.sh wrote)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/demo-study}
site=${SITE:-maps/default}
study="$out/study"
mkdir -p "$study"
echo "participant,order,platform,recording" > "$study/study.csv"
for f in "$site"/scenarios/*.yaml; do
    name=$(basename "$f" .yaml)
    build/bin/log-merge --quiet --out "$study/lab_$name.lcm" "$out/lab.lcm" "$out/lab_$name.lcm"
    build/bin/log-merge --quiet --out "$study/road_$name.lcm" "$out/road/localizer.lcm" "$out/road_$name.lcm"
    echo "demo,lab_first,lab,lab_$name.lcm" >> "$study/study.csv"
    echo "demo,lab_first,road,road_$name.lcm" >> "$study/study.csv"
done
# The demo has no questionnaire: one participant's example ratings (a Bayes factor needs
# at least two participants, so the table says "too few pairs").
printf 'participant,platform,measure,value\ndemo,lab,realism,3\ndemo,road,realism,4\ndemo,lab,presence,3\ndemo,road,presence,5\n' \
    > "$study/questionnaire.csv"
build/bin/study-report --site "$site" --questionnaire "$study/questionnaire.csv" --sessions "$study" \
    --out "$out/report" --json "$out/report/report.json" --title "make demo: the crosswalk study, lab twin and road car"
echo "   decisions per encounter: $out/report/encounters.csv"
echo "   open $out/report/report.html"
