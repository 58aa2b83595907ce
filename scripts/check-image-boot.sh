#!/usr/bin/env bash
# The SD-image install's boot check, as far as it goes without a Jetson: builds a GPT disk
# image with an ext4 APP partition at sector 28672 (as on Jetson SD cards), runs
# `jetpilot image install` into it with the aarch64 binary and the aarch64 ONNX Runtime
# library, copies the installed root filesystem out with debugfs, then checks
#   - `systemd-analyze verify` on the units as installed (with their drop-ins),
#   - the installed binary's `--version` under qemu-aarch64,
#   - the installed binary loading the installed model through the installed ONNX Runtime
#     library under qemu-aarch64 (`run --dry-run` on bundled sample frames).
# Installs what it needs (scripts/install-build-deps.sh; the arm64 libstdc++ for qemu).
#
#   scripts/check-image-boot.sh [AARCH64_BINARY]   # default: target/aarch64-unknown-linux-gnu/release/jetpilot
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${1:-${CARGO_TARGET_DIR:-target}/aarch64-unknown-linux-gnu/release/jetpilot}
[ -x "$BIN" ] || { echo "check-image-boot: no aarch64 binary at $BIN (scripts/build-aarch64.sh)" >&2; exit 1; }
scripts/install-build-deps.sh
need=()
for p in qemu-user libstdc++6-arm64-cross libgcc-s1-arm64-cross; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
ORT=$(JETPILOT_ORT_ARCH=aarch64 JETPILOT_ORT_DIR="$PWD/.cache/ort-aarch64" scripts/install-onnxruntime.sh)
# The PC's jetpilot runs the install: $JETPILOT_HOST_BIN (CI passes the test build's),
# else a release build.
HOST=${JETPILOT_HOST_BIN:-}
if [ -z "$HOST" ]; then
  cargo build --release --locked --quiet
  HOST=${CARGO_TARGET_DIR:-target}/release/jetpilot
fi

W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
SECTOR=28672
OFFSET=$((SECTOR * 512))
IMG="$W/jetbot.img"
truncate -s $((OFFSET + 257 * 1048576)) "$IMG"
sgdisk -o -n 2:2048:+1M -c 2:TBC -n 3:4096:+1M -c 3:RP1 \
  -n 1:$SECTOR:$((SECTOR + 256 * 2048 - 1)) -c 1:APP "$IMG" >/dev/null
mkdir -p "$W/skel/etc" "$W/skel/usr/bin" "$W/skel/lib/systemd/system" "$W/skel/var/lib"
echo jetbot >"$W/skel/etc/hostname"
fakeroot /sbin/mkfs.ext4 -q -F -b 4096 -E offset=$OFFSET -d "$W/skel" "$IMG" 256M
"$HOST" -q model init --arch resnet18 --input-size 64 --seed 1 -o "$W/model.onnx"

"$HOST" image install --image "$IMG" --kit jetbot --model "$W/model.onnx" \
  --binary "$BIN" --onnxruntime "$ORT"

ROOT="$W/root"
mkdir -p "$ROOT"
for d in usr etc lib var; do
  /sbin/debugfs -R "rdump /$d $ROOT" "$IMG?offset=$OFFSET" 2>/dev/null
done
cmp "$ROOT/usr/bin/jetpilot" "$BIN"

# systemd-analyze verify on the installed units, against this machine's unit library.
VROOT="$W/verify"
mkdir -p "$VROOT/lib/systemd" "$VROOT/bin"
cp -r "$(readlink -f /lib/systemd/system)" "$VROOT/lib/systemd/system"
cp -r "$ROOT/etc" "$ROOT/usr" "$VROOT/"
cp "$ROOT"/lib/systemd/system/jetpilot*.service "$VROOT/lib/systemd/system/"
for b in systemd-sysusers touch; do printf '#!/bin/sh\nexit 0\n' >"$VROOT/bin/$b"; chmod 755 "$VROOT/bin/$b"; done
for unit in jetpilot.service jetpilot-firstboot.service; do
  if out=$(systemd-analyze verify --root="$VROOT" "$unit" 2>&1) && ! grep -qi jetpilot <<<"$out"; then
    echo "verify installed $unit: ok"
  else
    echo "$out" >&2
    echo "check-image-boot: FAIL: systemd-analyze verify of the installed $unit" >&2
    exit 1
  fi
done

Q=(qemu-aarch64 -L /usr/aarch64-linux-gnu)
"${Q[@]}" "$ROOT/usr/bin/jetpilot" --version
cat >"$W/check.toml" <<TOML
[camera]
source = "folder"
path = "$PWD/config/samples/road"
[model]
path = "$ROOT/var/lib/jetpilot/model.onnx"
[runtime]
library = "$ROOT/usr/lib/jetpilot/libonnxruntime.so.1.23.2"
[motors]
backend = "log"
TOML
env -u ORT_DYLIB_PATH -u LD_LIBRARY_PATH "${Q[@]}" "$ROOT/usr/bin/jetpilot" run --config "$W/check.toml" --dry-run >"$W/dry.txt"
grep -q "policy" "$W/dry.txt" || { cat "$W/dry.txt" >&2; echo "check-image-boot: FAIL: no pipeline from the installed binary" >&2; exit 1; }
echo "check-image-boot: ok: the installed binary loads the installed model through the installed ONNX Runtime under qemu-aarch64"
