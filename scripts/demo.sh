#!/usr/bin/env bash
# make demo: the paper's section 4 experiment on the simulated rig, with the
# shipped Texture_3_color model: 40 random poses in the P1 ranges, each frame
# rendered at the stage's true angles and estimated by poseinfer's library.
# usage: scripts/demo.sh [OUT_DIR]    (environment: MODEL, TEXTURE, POSES, SEED)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/demo-$(date +%Y%m%d-%H%M%S)}
POSES=${POSES:-40}

echo "demo: $POSES poses on the simulated stage; results go to $OUT"
scripts/simrig.sh "$OUT" --random "$POSES" --seed "${SEED:-1}" --save-frames
.venv/bin/python scripts/rig_plots.py "$OUT"
# what the sphere finder saw in three of the frames, the first by name (docs/rig.md,
# "Checking the camera's view"), with the model and camera file the rig ran with
source scripts/simrig_env.sh
cam_opts=()
[ -z "$CAMERA_FILE" ] || cam_opts+=(--camera-file "$CAMERA_FILE")
mapfile -t FIRST < <(find "$OUT/frames" -name '*.png' | sort | head -n 3)
if [ ${#FIRST[@]} -gt 0 ]; then
  .venv/bin/python scripts/sphere_check.py --model "$MODEL" "${cam_opts[@]}" --out "$OUT/check" "${FIRST[@]}" ||
    echo "demo: sphere_check refused or could not read a frame (above)"
fi
echo
echo "demo: done. Per-pose CSV, summary and plots are in $OUT/:"
echo "  poses.csv  summary.md  boxplot.svg  rig_box.png  rig_panels.png  rig_poses.png  frames/  check/"
