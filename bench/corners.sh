#!/bin/sh
# Errors at the corners of the trained range, where all three angles lie
# within SPAN deg (default 6, a multiple of 3) of +-30 deg (docs/bench/training.md). Uniform and grid poses
# almost never land there, so validation does not see them.
#
#   bench/corners.sh MODEL.onnx [MODEL.onnx ...]
#
# Renders N poses (default 25) in each of the 8 corner cubes, once, into
# $OUT/all/test (default OUT=build/bench/corners-SPAN), then evaluates every model
# on all of them with `posetrain eval` (tables and figures in $OUT/eval-NAME).
# TEX is the texture (default build/textures/Texture_3_color.png).
set -eu
cd "$(dirname "$0")/.."
TEX=${TEX:-build/textures/Texture_3_color.png}
OUT=${OUT:-build/bench/corners-${SPAN:-6}}
N=${N:-25}
SPAN=${SPAN:-6}
if [ $# -eq 0 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
  sed -n '2,/^[^#]/p' "$0" | grep '^#' | sed 's/^# \{0,1\}//'
  exit 0
fi
[ -f "$TEX" ] || { echo "corners: $TEX: no such texture (make textures)" >&2; exit 2; }
lo=$((30 - SPAN))
span() { if [ "$1" = p ]; then echo "$lo,30"; else echo "-30,-$lo"; fi; }
if [ ! -f "$OUT/all/.done" ]; then
  mkdir -p "$OUT/all/test"
  seed=100
  for sx in p n; do for sy in p n; do for sz in p n; do
    d="$OUT/octants/$sx$sy$sz"
    .venv/bin/sim dataset --texture "$TEX" --out "$d" --sampling continuous --seed $seed --quiet \
      --range-x="$(span $sx)" --range-y="$(span $sy)" --range-z="$(span $sz)" \
      --train 0 --val 0 --test "$N" --offgrid-test 0
    cp "$d"/test/*.png "$OUT/all/test/"
    seed=$((seed + 1))
  done; done; done
  touch "$OUT/all/.done"
fi
for m in "$@"; do
  name=$(basename "$m" .onnx)
  [ "$name" = model ] && name=$(basename "$(dirname "$m")")
  .venv/bin/posetrain eval --model "$m" --data "$OUT/all" --splits test --threads 1 --no-progress \
    --label "$name, corners" --out "$OUT/eval-$name"
done
