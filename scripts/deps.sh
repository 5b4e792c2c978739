#!/usr/bin/env bash
# Install what spherepose needs and is missing: Debian packages, then a .venv
# from the pinned requirements. Safe to rerun: each step checks before it acts.
set -euo pipefail
cd "$(dirname "$0")/.."

DEBIAN_PACKAGES=(
  build-essential pkg-config clang libclang-rt-14-dev valgrind
  gcc-avr avr-libc binutils-avr avrdude simavr libsimavr-dev libelf-dev arduino-core-avr
  libopencv-dev libserialport-dev libcmocka-dev gstreamer1.0-plugins-base
  libosmesa6 libegl1 libgl1
)

missing=()
for p in "${DEBIAN_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "deps: installing Debian packages: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${missing[@]}"
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "deps: creating .venv"
  "$PY" -m venv .venv
fi
# Reinstall only when requirements.txt or pyproject.toml changed since the last install.
stamp=.venv/.spherepose-installed
NEED_GB=8  # the install peaks at 7.4 GB (measured), then build and tests add about 0.5
if [ ! -f "$stamp" ] || [ requirements.txt -nt "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "deps: installing Python packages from requirements.txt (first time: several GB, mostly PyTorch)"
  pip_install() { .venv/bin/pip install -q --disable-pip-version-check --no-cache-dir "$@"; }
  # A fresh install holds about 7.4 GB at its peak (scripts/pip_steps.py); say so
  # before starting rather than let pip stop half-way on a full disk. What .venv
  # already holds counts (a rerun after a failed install needs only the rest).
  # pip downloads into TMPDIR (/tmp by default), here the same disk.
  free_kb=$(df -Pk .venv | awk 'NR == 2 { print $4 }')
  held_kb=$(du -sk .venv | cut -f1)
  if [ ! -f "$stamp" ] && [ $((free_kb + held_kb)) -lt $((NEED_GB * 1024 * 1024)) ]; then
    echo "deps: $(pwd)/.venv needs about $NEED_GB GB for its first install; it holds" \
      "$((held_kb / 1024 / 1024)) GB and the disk has $((free_kb / 1024 / 1024)) GB free." \
      "Free some space and run it again." >&2
    exit 1
  fi
  # Resolve once, then install the plan in steps: one per large wheel, so that
  # only one large download sits on disk at a time. No wheel cache either.
  plan=$(mktemp)
  trap 'rm -f "$plan"' EXIT
  pip_install --dry-run --report "$plan" -r requirements.txt
  .venv/bin/python scripts/pip_steps.py "$plan" | while read -r -a pins; do
    pip_install --no-deps "${pins[@]}" </dev/null  # stdin is the plan
  done
  broken=$(.venv/bin/pip check --disable-pip-version-check) || { echo "deps: $broken" >&2; exit 1; }
  pip_install --no-deps --no-build-isolation -e .
  touch "$stamp"
fi

# ONNX Runtime C API: library from the onnxruntime wheel, headers from Debian trixie.
if [ -x host/scripts/fetch_ort.sh ]; then
  host/scripts/fetch_ort.sh
fi
echo "deps: ok"
