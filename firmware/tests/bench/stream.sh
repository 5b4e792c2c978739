#!/bin/sh
# 1000 G-code lines streamed to the ELF in simavr with GRBL character
# counting (at most 127 bytes unanswered) while '?' arrives every 100 ms,
# as senders do. Passes when every line got "ok" and the motors made
# exactly the steps of the final position. About 3 minutes of wall time.
# Usage: tests/bench/stream.sh BUILD_DIR
set -eu
b=${1:-build}
gc=$b/stream.gcode
awk 'BEGIN { srand(3); print "G91 G1 F1200";
  for (i = 0; i < 999; i++) printf "X%.3f Y%.3f Z%.3f\n", rand() * 1.1 - 0.5, rand() * 1.1 - 0.5, rand() * 1.1 - 0.5 }' > "$gc"
# Expected steps: the firmware sums the relative moves in single precision
# and rounds once; the sums here are kept to 3 decimals (exact for these inputs
# to well under half a step).
want=$(awk 'NR > 1 { gsub(/[XYZ]/, " "); x += $1; y += $2; z += $3 }
  END { printf "STEPS %d %d %d", (x < 0 ? -int(-x * 800 + 0.5) : int(x * 800 + 0.5)),
    (y < 0 ? -int(-y * 800 + 0.5) : int(y * 800 + 0.5)), (z < 0 ? -int(-z * 800 + 0.5) : int(z * 800 + 0.5)) }' "$gc")
printf '100 stream %s 100\n160000 end\n' "$gc" > "$b/stream.script"
out=$("$b/simrun" "$b/spherepose-stage.elf" "$b/stream.script")
echo "$out" | grep -E '^STREAM|^STEPS|^error'
echo "$out" | grep -q '^STREAM sent 1000 ok 1000 error 0$' || { echo "stream: FAILED (replies)"; exit 1; }
echo "$out" | grep -q "^$want\$" || { echo "stream: FAILED (want $want)"; exit 1; }
echo "stream: passed"
