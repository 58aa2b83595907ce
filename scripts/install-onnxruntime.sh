#!/usr/bin/env bash
# Installs the ONNX Runtime shared library jetpilot loads at run time, from the pinned PyPI
# wheel onnxruntime==1.23.2 (the newest release built for glibc 2.27: it runs here and on
# JetPack 4.6). Idempotent: does nothing when the library is already there.
#
#   scripts/install-onnxruntime.sh        # prints the library's path
#   JETPILOT_ORT_ARCH=aarch64 JETPILOT_ORT_DIR=.cache/ort-aarch64 scripts/install-onnxruntime.sh
#                                         # the robot's library, for `jetpilot image install`
#
# Destination: $JETPILOT_ORT_DIR, else ${XDG_DATA_HOME:-~/.local/share}/jetpilot/onnxruntime,
# one of the places jetpilot searches by itself.
set -euo pipefail

VERSION=1.23.2
DEST=${JETPILOT_ORT_DIR:-${XDG_DATA_HOME:-$HOME/.local/share}/jetpilot/onnxruntime}
LIB="$DEST/libonnxruntime.so.$VERSION"

if [ -f "$LIB" ]; then
  echo "$LIB"
  exit 0
fi

case "${JETPILOT_ORT_ARCH:-$(uname -m)}" in
  x86_64) PLATFORM=manylinux_2_27_x86_64 ;;
  aarch64 | arm64) PLATFORM=manylinux_2_27_aarch64 ;;
  *) echo "install-onnxruntime: no onnxruntime wheel for ${JETPILOT_ORT_ARCH:-$(uname -m)}" >&2; exit 1 ;;
esac

PY=${PYTHON:-python3}
if ! "$PY" -m pip --version >/dev/null 2>&1; then
  echo "install-onnxruntime: needs $PY with pip (apt-get install python3-pip)" >&2
  exit 1
fi

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
# The library inside is the same for every CPython tag; ask for one that exists.
"$PY" -m pip download --quiet --no-deps --only-binary=:all: \
  --platform "$PLATFORM" --python-version 3.11 --implementation cp \
  "onnxruntime==$VERSION" -d "$TMP" >&2

WHEEL=$(ls "$TMP"/onnxruntime-"$VERSION"-*.whl)
mkdir -p "$DEST"
"$PY" - "$WHEEL" "$DEST" "$VERSION" <<'PYEOF'
import os, sys, zipfile
wheel, dest, version = sys.argv[1:4]
wanted = {
    f"onnxruntime/capi/libonnxruntime.so.{version}": f"libonnxruntime.so.{version}",
    "onnxruntime/capi/libonnxruntime_providers_shared.so": "libonnxruntime_providers_shared.so",
}
with zipfile.ZipFile(wheel) as z:
    for member, name in wanted.items():
        tmp = os.path.join(dest, name + ".part")
        with z.open(member) as src, open(tmp, "wb") as out:
            out.write(src.read())
        os.replace(tmp, os.path.join(dest, name))
PYEOF
ln -sf "libonnxruntime.so.$VERSION" "$DEST/libonnxruntime.so"
echo "$LIB"
