#!/usr/bin/env bash
# make bench: every part's benchmark in turn. Each compares side by side in
# one run (ratios), because the machines are shared and noisy; the reports
# land in docs/bench/<part>.md (summarised in docs/benchmarks.md) and the raw
# output in build/bench/.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
mkdir -p build/bench
echo "bench: machine: $(nproc) cores, $(lscpu | sed -n 's/^Model name: *//p'), $(date -u +%F)"

echo "=== rendering: frames/s for the P1 dataset, 1 worker vs all cores"
$PY bench/render_fps.py --json build/bench/render_fps.json | tee build/bench/render_fps.txt

echo "=== stage: step rates and interrupt time of the firmware in simavr (simulated cycles)"
$PY bench/stage_steprate.py --markdown docs/bench/stage.md | tee build/bench/stage_steprate.txt

echo "=== host: per-frame decode / preprocess / inference, poseinfer vs bare OrtRun vs Python"
make --no-print-directory -C host bench | tee build/bench/infer.txt

echo "=== host daemon: 50 clients x 20 requests, p50/p99 and RSS (docs/bench/daemon.md)"
$PY bench/daemon_load.py --markdown build/bench/daemon_load.md | tee build/bench/daemon_load.txt

echo "=== real scenes: the default model on the independent ray-caster's frames (docs/bench/realscene.md)"
$PY bench/realscene.py --n 100 --seed 0 --out build/bench/realscene --no-progress | tee build/bench/realscene.txt

echo "=== confidence: flag rates on fresh held-out frames, both renderers (docs/bench/confidence.md)"
$PY bench/flag_rates.py --no-progress --markdown build/bench/flag_rates.md | tee build/bench/flag_rates.txt

echo "=== firmware: flash and RAM"
make --no-print-directory -C firmware size | tee build/bench/firmware_size.txt
