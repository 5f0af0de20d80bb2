# Sourced by the project's shell scripts, first thing after `set -euo pipefail`:
#   . "$(dirname "$0")/script-args.sh" options [ALLOWED...] -- "$@"
#   . "$(dirname "$0")/.../tools/script-args.sh" none -- "$@"
# --help or -h first: prints the script's header comment (line 2 up to `set -euo pipefail`)
# and exits 0. "options": a first argument starting with - that is not ALLOWED is an error;
# "none": the script takes no arguments, so any is an error. Errors exit 2, naming it.
script_args() {
  local kind=$1 me; shift
  me=$(basename "$0")
  local allowed=()
  while [ "$1" != "--" ]; do allowed+=("$1"); shift; done
  shift
  case "${1:-}" in
    -h|--help) sed -n '2,/^set -euo/{/^#/s/^# \{0,1\}//p}' "$0"; exit 0;;
  esac
  [ $# -gt 0 ] || return 0
  local a
  for a in "${allowed[@]}"; do [ "$1" = "$a" ] && return 0; done
  if [ "$kind" = none ]; then
    echo "$me: unknown argument '$1' (see --help)" >&2; exit 2
  elif [ "${1#-}" != "$1" ]; then
    echo "$me: unknown option '$1' (see --help)" >&2; exit 2
  fi
}
script_args "$@"
