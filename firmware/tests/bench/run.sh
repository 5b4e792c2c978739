#!/bin/sh
# Step-rate benchmark of the firmware ELF in simavr (simulated cycles):
# each scenario reports exact step counts, the shortest step interval per
# axis and the longest step-interrupt time (nested interrupts included).
# Usage: tests/bench/run.sh BUILD_DIR
set -eu
b=${1:-build}
elf=$b/spherepose-stage.elf
entry=$(avr-nm "$elf" | awk '/ __vector_11$/ {print $1}')
retis=$(avr-objdump -d "$elf" | awk '/<__vector_11>:/ {f = 1} f && /reti/ {sub(":", "", $1); printf ",%s", $1} f && /^$/ {exit}')
for s in tests/bench/*.txt; do
  out=$(SIMRUN_ISR="$entry$retis" "$b/simrun" "$elf" "$s")
  echo "== $(basename "$s" .txt): $(sed -n '1s/^# //p' "$s")"
  echo "$out" | grep -E '^<Idle|^STEPS|^AXIS|^ISR_CYCLES|^MIN_PULSE|^SHORT' | sed 's/^/   /'
done
