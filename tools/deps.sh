#!/usr/bin/env bash
# Installs what a fresh Debian 12 needs to build and test the project (and what the
# README's own commands use: procps for sysctl, iproute2 for ip). Idempotent:
# installs only what is missing. Called by `make deps` (and by make, make test and
# make demo when the stamp is missing or older than this script).
#   tools/deps.sh [--check]   (--check: installs nothing; exit 0 when nothing is missing)
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/script-args.sh" options --check -- "$@"
cd "$(dirname "$0")/.."

APT_PKGS="build-essential pkg-config python3 python3-venv python3-pip libglib2.0-0 libglib2.0-dev \
libyaml-dev libeigen3-dev libpcl-dev liboctomap-dev libccd-dev libceres-dev libpng-dev can-utils libcjson-dev zlib1g-dev \
chromium chromium-driver mono-mcs mono-runtime libmono-system-runtime-serialization4.0-cil procps iproute2"
# nodejs + npm bundle the webui pages at build time (esbuild from npm); a machine whose
# node already brings npm (e.g. NodeSource's nodejs) must not get Debian's npm on top.
command -v npm >/dev/null 2>&1 || APT_PKGS="$APT_PKGS nodejs npm"

missing=""
for p in $APT_PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done

# --check: exit 0 if nothing is missing (make runs this on every invocation; it is cheap).
# Every pinned Python package counts, the tests' oracles (pyubx2, pynmeagps, cantools) and
# the benchmarks' baselines (small_gicp, foxglove-sdk) as much as the build's lcm; what is
# missing or at another version is named on stderr.
if [ "${1:-}" = "--check" ]; then
  [ -z "$missing" ] || { echo "deps: missing Debian packages:$missing" >&2; exit 1; }
  [ -f .venv/.deps-ok ] && [ -f .venv/lcm/include/lcm/lcm.h ] || exit 1
  .venv/bin/python - tools/requirements.txt <<'PY'
import importlib.metadata as md, sys
bad = []
for line in open(sys.argv[1]):
    line = line.split("#")[0].strip()
    if not line:
        continue
    name, _, want = line.partition("==")
    try:
        have = md.version(name)
    except md.PackageNotFoundError:
        have = None
    if have != want:
        bad.append(f"{name}=={want} ({'not installed' if have is None else 'installed ' + have})")
if bad:
    print("deps: Python packages of tools/requirements.txt: " + ", ".join(bad), file=sys.stderr)
sys.exit(1 if bad else 0)
PY
  exit $?
fi
if [ -n "$missing" ]; then
  echo "deps: installing Debian packages:$missing"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
fi

PY=${PYTHON:-/usr/bin/python3}
[ -x "$PY" ] || PY=python3
if [ ! -x .venv/bin/python ]; then
  echo "deps: creating .venv with $PY"
  "$PY" -m venv .venv
fi
if ! .venv/bin/python -m pip install -q --disable-pip-version-check -r tools/requirements.txt; then
  echo "deps: pip install failed (PyPI must be reachable)" >&2; exit 1
fi
# One stable path to the LCM library, headers and tools shipped in the lcm wheel.
site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["platlib"])')
ln -sfn "$site" .venv/lcm
[ -f .venv/lcm/include/lcm/lcm.h ] || { echo "deps: lcm wheel has no C headers at $site/include" >&2; exit 1; }

# Large LCM messages (a LiDAR sweep is ~330-600 KB) need a big socket receive buffer:
# every URL the project uses asks for recv_buf_size=8388608, which the kernel caps at rmem_max.
want=16777216
have=$(cat /proc/sys/net/core/rmem_max 2>/dev/null || echo 0)
if [ "$have" -lt "$want" ]; then
  if [ "$(id -u)" -eq 0 ] && sysctl -q -w net.core.rmem_max=$want 2>/dev/null; then
    echo "deps: net.core.rmem_max $have -> $want"
  else
    echo "deps: warning: net.core.rmem_max is $have; run 'sysctl -w net.core.rmem_max=$want' as root for large LCM messages" >&2
  fi
fi
touch .venv/.deps-ok
