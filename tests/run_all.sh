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

# count_cmocka LOG: sums cmocka's "[  PASSED  ] N test(s)." and "[  FAILED  ] N test(s)." lines.
count_cmocka() {
  local p f
  p=$(grep -aE '^\[  PASSED  \] [0-9]+ test' "$1" | awk '{s += $4} END {print s + 0}')
  f=$(grep -aE '^\[  FAILED  \] [0-9]+ test' "$1" | awk '{s += $4} END {print s + 0}')
  echo "$p $f"
}

# count_pytest LOG: reads pytest's closing line ("3 passed, 1 failed, 2 skipped in 4.2s").
count_pytest() {
  local line p f e
  line=$(grep -aE '[0-9]+ (passed|failed|error)' "$1" | tail -n 1)
  p=$(echo "$line" | grep -oE '[0-9]+ passed' | awk '{print $1}')
  f=$(echo "$line" | grep -oE '[0-9]+ failed' | awk '{print $1}')
  e=$(echo "$line" | grep -oE '[0-9]+ errors?' | awk '{print $1}')
  echo "${p:-0} $(( ${f:-0} + ${e:-0} ))"
}

# run_suite NAME KIND CMD...: run one suite, tee its log, add its counts.
run_suite() {
  local name=$1 kind=$2; shift 2
  local log="$LOGS/$name.log" rc counts p f
  echo "=== $name: $*"
  "$@" 2>&1 | tee "$log"
  rc=${PIPESTATUS[0]}
  counts=$(count_"$kind" "$log")
  p=${counts% *}; f=${counts#* }
  if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then
    f=1   # the suite itself broke (build error, crash): count it as one failure
  fi
  total_pass=$((total_pass + p)); total_fail=$((total_fail + f))
  [ "$rc" -ne 0 ] && failed_suites+=("$name (exit $rc, log $log)")
  echo "=== $name: $p passed, $f failed"
}

run_suite firmware cmocka make --no-print-directory -C firmware test
run_suite host cmocka make --no-print-directory -C host test
run_suite rig cmocka make --no-print-directory -C host/rig test
run_suite python pytest "$PY" -m pytest -q -p no:cacheprovider tests

echo
if [ ${#failed_suites[@]} -gt 0 ]; then
  echo "Failed suites:"
  printf '  %s\n' "${failed_suites[@]}"
fi
echo "$total_pass passed, $total_fail failed"
[ "$total_fail" -eq 0 ] && [ ${#failed_suites[@]} -eq 0 ]
