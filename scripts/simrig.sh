#!/usr/bin/env bash
# Run poserig on the simulated rig: the firmware ELF in stagesim (simavr,
# UART on a pty), the virtual camera rendering the stage's true angles, and
# poserig driving both exactly as it drives a real rig. Every process this
# script starts is stopped on exit, on error and on Ctrl-C.
#
# usage: scripts/simrig.sh OUT_DIR [poserig options...]
#   environment: MODEL, TEXTURE, ELF, SEED, VCAM_OPTS (extra `sim vcam` options),
#   SCENE (rig scene the camera renders, default sim/scenes/rig.json; empty: plain renders),
#   CAMERA_FILE (the camera file poserig reads, default the scene's: sim/scenes/rig_camera.json)
set -euo pipefail
cd "$(dirname "$0")/.."

if [ $# -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
  sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
OUT=$1; shift

source scripts/simrig_env.sh # MODEL, SCENE, CAMERA_FILE
TEXTURE=${TEXTURE:-build/textures/Texture_3_color.png}
ELF=${ELF:-firmware/build/spherepose-stage.elf}
STAGESIM=sim/stage/build/stagesim
POSERIG=host/build/rig/poserig
VCAM=.venv/bin/sim

for f in "$MODEL" "$ELF" "$STAGESIM" "$POSERIG" "$VCAM"; do
  [ -e "$f" ] || { echo "simrig: $f is missing (run 'make build' first)" >&2; exit 2; }
done
# The default texture is generated (deterministically) when missing or older than its generator.
if [ "$TEXTURE" = build/textures/Texture_3_color.png ] &&
   { [ ! -f "$TEXTURE" ] || [ -n "$(find textures -name '*.py' -newer "$TEXTURE")" ]; }; then
  .venv/bin/textures generate --out build/textures >&2
fi
[ -f "$TEXTURE" ] || { echo "simrig: texture $TEXTURE is missing" >&2; exit 2; }

mkdir -p "$OUT"
# A simulated board seen for the first time has never stored its settings: it starts on the
# firmware's defaults (and says so), which is what this rig is meant to run on.
rig_opts=()
[ -f "$OUT/eeprom.bin" ] || rig_opts+=(--allow-default-settings)
[ -z "$CAMERA_FILE" ] || rig_opts+=(--camera-file "$CAMERA_FILE")
scene_opts=()
[ -z "$SCENE" ] || scene_opts+=(--scene "$SCENE")
RUN=$(mktemp -d "${TMPDIR:-/tmp}/simrig.XXXXXX")
pids=()
cleanup() {
  local rc=$?
  trap - EXIT INT TERM
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  rm -rf "$RUN"
  exit "$rc"
}
trap cleanup EXIT
trap 'echo "simrig: interrupted" >&2; exit 130' INT
trap 'exit 143' TERM

# wait_line FILE PREFIX: the value after PREFIX on FILE's first such line, within 30 s.
wait_line() {
  local i line
  for i in $(seq 300); do
    line=$(grep -m1 "^$2 " "$1" 2>/dev/null || true)
    [ -n "$line" ] && { echo "${line#"$2" }"; return 0; }
    sleep 0.1
  done
  echo "simrig: no '$2' line from $1 after 30 s" >&2
  return 1
}

# The stage: the same ELF one flashes, in simavr; its EEPROM kept in OUT.
"$STAGESIM" --state-socket "$RUN/state.sock" --eeprom "$OUT/eeprom.bin" "$ELF" \
  > "$RUN/stagesim.out" 2> "$OUT/stagesim.log" &
pids+=($!)
PTY=$(wait_line "$RUN/stagesim.out" PTY)
wait_line "$RUN/stagesim.out" STATE > /dev/null

# The camera: renders at the true angles the stage reports.
# shellcheck disable=SC2086
"$VCAM" vcam --texture "$TEXTURE" --socket "$RUN/cam.sock" --stage-state "$RUN/state.sock" \
  --seed "${SEED:-1}" "${scene_opts[@]}" ${VCAM_OPTS:-} > "$RUN/vcam.out" 2> "$OUT/vcam.log" &
pids+=($!)
wait_line "$RUN/vcam.out" VCAM > /dev/null

echo "simrig: stage on $PTY, camera unix:$RUN/cam.sock" >&2
"$POSERIG" --port "$PTY" --camera "unix:$RUN/cam.sock" --model "$MODEL" --out "$OUT" "${rig_opts[@]}" "$@"
