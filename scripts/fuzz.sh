#!/usr/bin/env bash
# Fuzzes the parsers that read outside input, with cargo-fuzz (libFuzzer, AddressSanitizer)
# (nightly, or stable with RUSTC_BOOTSTRAP=1): the targets in scripts/fuzz/fuzz_targets/, each calling the
# project's real entry point. Usage: scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
# (default 60 s, every target). Installs cargo-fuzz where it is missing. Seeds each corpus
# (kept in target/fuzz-corpus/, never committed) from the shipped configs, the sample
# frames and, when given as JETPILOT_REALDATA (e.g. ../shared/realdata), real JetBot file
# names and a real tub. Limits per input: 1 s (a hang), 512 MiB (out of memory).
# A crash stops that target with its input in scripts/fuzz/artifacts/<target>/.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH=${1:-60}
shift || true
CARGO_FUZZ_VERSION=0.13.2
if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz.sh: cargo install cargo-fuzz --version $CARGO_FUZZ_VERSION --locked" >&2
  cargo install cargo-fuzz --version "$CARGO_FUZZ_VERSION" --locked --quiet
fi
# libFuzzer's instrumentation needs -Z flags: the installed nightly where there is one, else
# the stable toolchain with RUSTC_BOOTSTRAP=1 (its rust-std ships the sanitizer runtimes).
if rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
  TOOLCHAIN=+nightly
else
  TOOLCHAIN=
  export RUSTC_BOOTSTRAP=1
fi
# The fuzz build (sanitizer flags: its own copy of every dependency) is kept outside the
# checkout, so a fresh clone (CI) rebuilds only jetpilot and the targets.
FUZZ_TARGET_DIR=${JETPILOT_FUZZ_TARGET_DIR:-$HOME/.cache/jetpilot/fuzz-target}
TARGETS=("$@")
if [ ${#TARGETS[@]} -eq 0 ]; then
  TARGETS=(config_toml xy_names web_messages frame_convert image_tables pytorch_pth onnx_model tub_reader)
fi
CORPUS=target/fuzz-corpus
mkdir -p "$CORPUS"/{config_toml,xy_names,web_messages,frame_convert,image_tables,pytorch_pth,onnx_model,tub_reader}
cp -f config/*.toml config/tracks/*.toml "$CORPUS/config_toml/" 2>/dev/null || true
printf 'xy_150_060_a5f98000-ef75-11f1-9234-0123456789ab.jpg' >"$CORPUS/xy_names/uuid1"
printf 'xy_012_154_0f1e2d3c-4b5a-4978-8695-a4b3c2d1e0f9.jpeg' >"$CORPUS/xy_names/uuid4"
printf '{"type":"label","kind":"xy","seq":7,"x":150,"y":60}' >"$CORPUS/web_messages/label"
printf '{"type":"gains","speed_gain":0.2,"steering_gain":0.2,"steering_kd":0,"steering_bias":0,"steering_ki":0}' >"$CORPUS/web_messages/gains"
printf 'token=abc\nHost: 127.0.0.1:8887\nCookie: jetpilot_token=abc; x=y\nAuthorization: Bearer abc\nOrigin: http://127.0.0.1:8887' >"$CORPUS/web_messages/headers"
{ printf '\x02\x10\x08\x01'; head -c 2000 config/samples/road/road_000.jpg; } >"$CORPUS/frame_convert/mjpeg"
{ printf '\x01\x10\x08\x00'; head -c 600 /dev/urandom; } >"$CORPUS/frame_convert/yuyv"
if [ -n "${JETPILOT_REALDATA:-}" ] && [ -d "$JETPILOT_REALDATA" ]; then
  n=0
  for f in "$JETPILOT_REALDATA"/jetbot_xy_*/*/xy_*.jpg "$JETPILOT_REALDATA"/jetbot_xy_*/xy_*.jpg; do
    [ -f "$f" ] || continue
    basename "$f" | tr -d '\n' >"$CORPUS/xy_names/real_$n"
    n=$((n + 1))
    [ $n -ge 20 ] && break
  done
  tub="$JETPILOT_REALDATA/donkey_tub_tarp"
  if [ -f "$tub/manifest.json" ]; then
    { cat "$tub/manifest.json"; printf '\n\0\n'; head -n 20 "$tub/catalog_0.catalog"; } >"$CORPUS/tub_reader/real"
  fi
  first_jpg=$(find "$JETPILOT_REALDATA" -name '*.jpg' -print -quit)
  [ -n "$first_jpg" ] && { printf '\x02\x40\x40\x00'; head -c 8000 "$first_jpg"; } >"$CORPUS/frame_convert/real_mjpeg"
fi
status=0
for t in "${TARGETS[@]}"; do
  echo "== fuzz $t for ${SECONDS_EACH}s" >&2
  if ! cargo $TOOLCHAIN fuzz run --fuzz-dir scripts/fuzz --target-dir "$FUZZ_TARGET_DIR" "$t" "$CORPUS/$t" -- \
    -max_total_time="$SECONDS_EACH" -timeout=1 -rss_limit_mb=512 -max_len=65536 \
    -print_final_stats=1 2>&1 | tail -n 12; then
    status=1
  fi
done
# The tub and .pth targets' scratch folders (one per fuzzer process, remade each input).
rm -rf "${TMPDIR:-/tmp}"/jetpilot-fuzz-tub-* "${TMPDIR:-/tmp}"/jetpilot-fuzz-pth-*
exit $status
