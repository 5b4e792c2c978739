#!/usr/bin/env bash
# ONNX Runtime for the C runtime, without touching the system's package state
# (ARCHITECTURE.md, "ONNX Runtime C API recipe"):
#   - the shared library: copied from the onnxruntime wheel in .venv;
#   - the headers: Debian trixie's libonnxruntime-dev, downloaded with apt-get
#     into a private state dir and unpacked with dpkg -x.
# Result: third_party/ort/{lib,include}. Safe to rerun: it does nothing when
# the pinned versions are already in place.
set -euo pipefail
cd "$(dirname "$0")/../.."

ORT_LIB_VERSION=1.31.1            # onnxruntime wheel (requirements.txt)
ORT_DEV_VERSION=1.21.0            # Debian trixie libonnxruntime-dev (headers, ORT_API_VERSION 21)
SUITE=trixie

DEST=third_party/ort
STATE=third_party/ort-apt
PY=${PY:-.venv/bin/python}

# --- library ---------------------------------------------------------------
if [ ! -f "$DEST/lib/libonnxruntime.so.$ORT_LIB_VERSION" ]; then
  capi=$("$PY" -c 'import onnxruntime, os; print(os.path.join(os.path.dirname(onnxruntime.__file__), "capi"))')
  have=$("$PY" -c 'import onnxruntime; print(onnxruntime.__version__)')
  if [ "$have" != "$ORT_LIB_VERSION" ]; then
    echo "fetch_ort: .venv has onnxruntime $have, want $ORT_LIB_VERSION (requirements.txt)" >&2
    exit 1
  fi
  mkdir -p "$DEST/lib"
  cp "$capi/libonnxruntime.so.$ORT_LIB_VERSION" "$DEST/lib/"
  # The wheel ships no links; the SONAME is libonnxruntime.so.1.
  ln -sf "libonnxruntime.so.$ORT_LIB_VERSION" "$DEST/lib/libonnxruntime.so.1"
  ln -sf libonnxruntime.so.1 "$DEST/lib/libonnxruntime.so"
  echo "fetch_ort: library $ORT_LIB_VERSION -> $DEST/lib"
fi

# --- headers ---------------------------------------------------------------
stamp="$DEST/include/.version"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$ORT_DEV_VERSION" ]; then
  # Same archive address and keyring as the machine's own Debian sources.
  src=""
  for f in /etc/apt/sources.list.d/*.sources; do
    [ -f "$f" ] && src=$f && break
  done
  if [ -z "$src" ]; then
    echo "fetch_ort: no /etc/apt/sources.list.d/*.sources to take the Debian archive address from" >&2
    exit 1
  fi
  uri=$(awk '/^URIs:/ { for (i = 2; i <= NF; i++) if ($i !~ /security/) { print $i; exit } }' "$src")
  keyring=$(awk '/^Signed-By:/ { print $2; exit }' "$src")
  if [ -z "$uri" ] || [ -z "$keyring" ]; then
    echo "fetch_ort: $src: no URIs/Signed-By" >&2
    exit 1
  fi
  mkdir -p "$STATE/lists/partial" "$STATE/cache/archives/partial" "$STATE/unpack"
  : > "$STATE/status"
  echo "deb [signed-by=$keyring] $uri $SUITE main" > "$STATE/sources.list"
  apt=(apt-get -q -o "Dir::Etc::SourceList=$PWD/$STATE/sources.list"
       -o Dir::Etc::SourceParts=/dev/null
       -o "Dir::State::Lists=$PWD/$STATE/lists"
       -o "Dir::Cache=$PWD/$STATE/cache"
       -o "Dir::State::Status=$PWD/$STATE/status"
       -o APT::Sandbox::User=root)
  "${apt[@]}" update >/dev/null
  (cd "$STATE" && "${apt[@]}" download "libonnxruntime-dev=$ORT_DEV_VERSION*")
  deb=$(ls "$STATE"/libonnxruntime-dev_"$ORT_DEV_VERSION"*.deb | head -n 1)
  rm -rf "$STATE/unpack" && mkdir -p "$STATE/unpack"
  dpkg -x "$deb" "$STATE/unpack"
  rm -rf "$DEST/include" && mkdir -p "$DEST/include"
  cp -r "$STATE/unpack/usr/include/onnxruntime/." "$DEST/include/"
  echo "$ORT_DEV_VERSION" > "$stamp"
  echo "fetch_ort: headers $ORT_DEV_VERSION -> $DEST/include"
fi
