#!/usr/bin/env bash
# Run every test suite of every part, keep going after a failing suite, and
# close with one line "N passed, N failed" that counts the tests of all suites.
# Logs: build/test-logs/<suite>.log
set -uo pipefail
cd "$(dirname "$0")/.."
LOGS=build/test-logs
mkdir -p "$LOGS"
PY=.venv/bin/python

total_pass=0
total_fail=0
failed_suites=()

# count_tests LOG: "PASSED FAILED" summed over cmocka's "[  PASSED  ] N test(s)." /
# "[  FAILED  ] N test(s)" lines and pytest's closing lines ("3 passed, 1 failed in 4.2s"):
# a part's `make test` may run both kinds.
count_tests() {
  local cp cf pp pf
  cp=$(grep -aE '^\[  PASSED  \] [0-9]+ test' "$1" | awk '{s += $4} END {print s + 0}')
  cf=$(grep -aE '^\[  FAILED  \] [0-9]+ test' "$1" | awk '{s += $4} END {print s + 0}')
  read -r pp pf < <(grep -aE '[0-9]+ (passed|failed|errors?)(,| ).* in [0-9.]+s' "$1" | awk '
    { for (i = 2; i <= NF; i++) {
        w = $i; sub(/[,=]+$/, "", w)
        if (w == "passed") p += $(i - 1)
        if (w == "failed" || w == "error" || w == "errors") f += $(i - 1) } }
    END { print p + 0, f + 0 }')
  echo "$((cp + pp)) $((cf + pf))"
}

# run_suite NAME CMD...: run one suite, tee its log, add its counts.
run_suite() {
  local name=$1; shift
  local log="$LOGS/$name.log" rc counts p f
  echo "=== $name: $*"
  "$@" 2>&1 | tee "$log"
  rc=${PIPESTATUS[0]}
  counts=$(count_tests "$log")
  p=${counts% *}; f=${counts#* }
  if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then
    f=1   # the suite itself broke (build error, crash): count it as one failure
  fi
  total_pass=$((total_pass + p)); total_fail=$((total_fail + f))
  [ "$rc" -ne 0 ] && failed_suites+=("$name (exit $rc, log $log)")
  echo "=== $name: $p passed, $f failed"
}

run_suite firmware make --no-print-directory -C firmware test
run_suite host make --no-print-directory -C host test
run_suite rig make --no-print-directory -C host/rig test
run_suite python "$PY" -m pytest -q -p no:cacheprovider tests

echo
if [ ${#failed_suites[@]} -gt 0 ]; then
  echo "Failed suites:"
  printf '  %s\n' "${failed_suites[@]}"
fi
echo "$total_pass passed, $total_fail failed"
[ "$total_fail" -eq 0 ] && [ ${#failed_suites[@]} -eq 0 ]
