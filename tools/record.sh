#!/usr/bin/env bash
# The session recorder: lcm-logger on the bus, one recording per participant and session.
#   tools/record.sh --participant ID --session ID [--dir DIR] [--split-mb N]
# Writes DIR/ID_SESSION.lcm.00, .01, ... (a new file every N MB, default 1024; lcm-logger's
# --increment: an existing file is never overwritten, so a restarted recorder goes on in
# the next number). The bus is $LCM_DEFAULT_URL (the supervisor sets it).
# Stop it by signalling its process group (the supervisor does): .venv/bin/lcm-logger is a
# Python wrapper whose SIGTERM leaves the real recorder running, and the real one closes
# the file cleanly on SIGTERM/SIGINT.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
participant="" session="" dir="recordings" split=1024
while [ $# -gt 0 ]; do
    case "$1" in
        --participant) participant=$2; shift 2 ;;
        --session) session=$2; shift 2 ;;
        --dir) dir=$2; shift 2 ;;
        --split-mb) split=$2; shift 2 ;;
        -h|--help) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "record.sh: unexpected argument '$1' (see --help)" >&2; exit 2 ;;
    esac
done
for v in participant session; do
    val=${!v}
    if [ -z "$val" ] || [[ ! "$val" =~ ^[A-Za-z0-9_-]+$ ]]; then
        echo "record.sh: --$v: expected letters, digits, _ or - (got '$val')" >&2; exit 2
    fi
done
mkdir -p "$dir"
echo "record.sh: recording ${LCM_DEFAULT_URL:-the default LCM URL} to $dir/${participant}_${session}.lcm.NN (new file every $split MB)"
exec "$root/.venv/bin/lcm-logger" --increment --split-mb="$split" "$dir/${participant}_${session}.lcm"
