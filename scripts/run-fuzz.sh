#!/usr/bin/env bash
# Builds the libFuzzer targets of the file readers (the `fuzz` preset: clang++, ASan + UBSan)
# and runs each one for SECONDS seconds from the committed corpus (tests/fuzz/corpus/<target>).
# New inputs go to a temporary folder, never into the repository; an input that crashes, leaks,
# breaks an expectation of the target, takes more than 1 s or allocates more than 256 MB at once
# is saved under out/fuzz/<target>/ and the script fails. See docs/reliability.md.
#
# The 1 s limit is wall-clock time: on a loaded machine an ordinary input can overrun it. A
# timeout input is therefore run again on its own (3 times, 1 s each); when it passes, the
# timeout is reported as not reproduced and fuzzing goes on for the rest of the time.
#
# Usage: scripts/run-fuzz.sh [SECONDS] [TARGET...]   (default: 25 s each; obj ply pose scene)
# PBVE_FUZZ_WORK=DIR keeps the new inputs in DIR/<target> (to merge into the corpus later).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-25}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(obj ply pose scene)

bash scripts/install-deps.sh fuzz
cmake --preset fuzz >/dev/null
cmake --build --preset fuzz

bin=build/fuzz/tests/fuzz
# llvm-symbolizer (Debian package llvm) gives stack traces with file and line.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1}
if [ -n "${PBVE_FUZZ_WORK:-}" ]; then
  scratch=$PBVE_FUZZ_WORK
else
  scratch=$(mktemp -d)
  trap 'rm -rf "$scratch"' EXIT
fi

# The value of libFuzzer's final statistic $2 in log $1 (0 when absent).
final_stat() { sed -n "s/^stat::$2: *//p" "$1" | tail -1 | grep . || echo 0; }

status=0
for t in "${targets[@]}"; do
  out=out/fuzz/$t
  mkdir -p "$out" "$scratch/$t"
  rm -f "$out"/fuzz-*.log
  echo "fuzz: $t for ${seconds} s (logs: $out/fuzz-*.log)"
  start=$(date +%s)
  deadline=$((start + seconds))
  runs=0
  segment=0
  failed=0
  while left=$((deadline - $(date +%s))) && [ "$left" -gt 0 ]; do
    segment=$((segment + 1))
    log=$out/fuzz-$segment.log
    set +e
    "$bin/fuzz_$t" -max_total_time="$left" -timeout=1 -rss_limit_mb=2048 -malloc_limit_mb=256 \
      -max_len=4096 -dict="tests/fuzz/dict/$t.dict" -print_final_stats=1 \
      -artifact_prefix="$out/" "$scratch/$t" "tests/fuzz/corpus/$t" >"$log" 2>&1
    rc=$?
    set -e
    runs=$((runs + $(final_stat "$log" number_of_executed_units)))
    [ $rc -eq 0 ] && break
    artifact=$(sed -n 's/.*Test unit written to //p' "$log" | tail -1)
    if grep -q 'ERROR: libFuzzer: timeout' "$log" && [ -f "$artifact" ] &&
      "$bin/fuzz_$t" -timeout=1 -runs=3 "$artifact" >"$log.replay" 2>&1; then
      echo "fuzz: $t: the timeout of $artifact did not reproduce (a busy machine); going on"
      mv "$artifact" "$artifact.not-reproduced"
      continue
    fi
    echo "fuzz: $t FAILED (exit status $rc): input $artifact, report $log:"
    grep -E 'ERROR|runtime error|SUMMARY|fuzz expectation' "$log" | head -20
    failed=1
    status=1
    break
  done
  if [ $failed -eq 0 ]; then
    # The last status line: coverage (cov), features (ft) and corpus size (corp: files/bytes).
    last=$(grep -E '^#[0-9]+.*cov: ' "$log" | tail -1 | sed 's/^.*cov: /cov: /')
    echo "fuzz: $t ok: $runs runs in $(($(date +%s) - start)) s ($segment segment(s)); ${last%% lim:*}"
  fi
done
exit $status
