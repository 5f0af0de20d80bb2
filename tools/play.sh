#!/usr/bin/env bash
# Plays an LCM log onto the bus in real time (lcm-logplayer), after checking how it ends:
# a torn last event (a recording cut by a power loss) is played up to the cut, with a
# warning naming its byte offset (lcm-logplayer itself stops there silently).
#   tools/play.sh LOG [lcm-logplayer options]      (the bus: $LCM_DEFAULT_URL)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
[ $# -ge 1 ] && [ "$1" != "-h" ] && [ "$1" != "--help" ] || { sed -n '2,5p' "$0" | sed 's/^# \{0,1\}//'; exit 0; }
log=$1; shift
[ -f "$log" ] || { echo "play.sh: $log: no such file" >&2; exit 2; }
"$root/.venv/bin/python" - "$log" <<'PY'
import struct, sys
path = sys.argv[1]
with open(path, "rb") as f:
    f.seek(0, 2); size = f.tell(); pos = n = 0
    while pos < size:
        f.seek(pos); h = f.read(28)
        if len(h) < 28 or struct.unpack(">I", h[:4])[0] != 0xEDA1DA01:
            break
        ch, ln = struct.unpack(">II", h[20:28])
        if pos + 28 + ch + ln > size:
            break
        pos += 28 + ch + ln; n += 1
    if pos < size:
        print(f"{path}: byte {pos}: warning: the log does not end cleanly there (a torn last event, as when a "
              f"recording is cut short, or damage); {n} events before it are played", file=sys.stderr)
    else:
        print(f"{path}: {n} events, ends cleanly", file=sys.stderr)
PY
exec "$root/.venv/bin/lcm-logplayer" "$@" "$log"
