#!/usr/bin/env bash
# make fuzz: builds each tests/fuzz/fuzz_*.c with libFuzzer, AddressSanitizer and
# UBSan (clang) and runs it for FUZZ_RUNS executions (default 1,000,000) from its
# seed corpus. Not part of make test.
# A target names what it links in its own header, one line each:
#   fuzz-sources: common/pb_log.c common/pb_err.c   (compiled with it; .c or .cpp)
#   fuzz-libs: -lcjson                              (optional extra link flags)
#   fuzz-max-len: 20000                             (optional; default 4096 bytes an input)
set -euo pipefail
# --help, and arguments this script does not take (tools/script-args.sh)
. "$(dirname "$0")/../../tools/script-args.sh" none -- "$@"
cd "$(dirname "$0")/../.."
RUNS=${FUZZ_RUNS:-1000000}
for p in clang libclang-rt-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="${missing:-} $p"
done
if [ -n "${missing:-}" ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
fi
out=build/fuzz
mkdir -p $out
CFLAGS="-g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined -Icommon -Imodules -Ibuild/gen/c -I.venv/lcm/include"
LCM="-L.venv/lcm/lib -Wl,-rpath,$PWD/.venv/lcm/lib -llcm"
summary=()
for f in tests/fuzz/fuzz_*.c tests/fuzz/fuzz_*.cpp; do
  [ -f "$f" ] || continue
  t=$(basename "${f%.*}")
  [ -z "${FUZZ_ONLY:-}" ] || [ "$t" = "$FUZZ_ONLY" ] || continue
  srcs=$(sed -n 's/.*fuzz-sources:\([^*]*\).*/\1/p' "$f" | head -1)
  libs=$(sed -n 's/.*fuzz-libs:\([^*]*\).*/\1/p' "$f" | head -1)
  [ -n "$srcs" ] || { summary+=("$t: FAILED (no fuzz-sources line)"); continue; }
  echo "== $t"
  cc=clang; case "$f" in *.cpp) cc="clang++ -std=c++17";; esac
  # a target that does not build is a failure of its own; the others still run
  if ! $cc $CFLAGS -o $out/$t "$f" $srcs $LCM $libs -lyaml -lm; then summary+=("$t: FAILED (does not build)"); continue; fi
  corpus=$out/$t.corpus; mkdir -p $corpus
  [ -d tests/fuzz/seeds/$t ] && cp -n tests/fuzz/seeds/$t/* $corpus/ 2>/dev/null || true
  log=$out/$t.log
  maxlen=$(sed -n 's/.*fuzz-max-len: *\([0-9]*\).*/\1/p' "$f" | head -1)
  if $out/$t -runs=$RUNS -max_len=${maxlen:-4096} -print_final_stats=1 $corpus > $log 2>&1; then
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' $log | grep -o '[0-9]*$')
    summary+=("$t: clean, $execs executions")
  else
    tail -40 $log; summary+=("$t: FAILED (see $log)")
  fi
done
printf '%s\n' "${summary[@]}"
! printf '%s\n' "${summary[@]}" | grep -q FAILED
