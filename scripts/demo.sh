#!/usr/bin/env bash
# The main job on a machine without a robot: a JetBot drives itself round the simulated
# JetBot mat under the real daemon (camera thread, ONNX Runtime, JetBot's steering law, the
# motor driver on a virtual PCA9685, the watchdog), with the web page on to watch it. It ends
# with the drive's summary (interventions, autonomy, laps) and the trace, .cache/demo/trace.png.
#
# The first run makes its policy, once, in a few minutes: 600 frames collected on the mat
# the way JetBot's road-following notebook does (`sim --scatter`) and 600 more on random
# road layouts (`--random-layouts`), and the ImageNet EfficientNet-Lite0 with its output
# layer fitted to them in closed form (`train probe`). It is cached in
# .cache/demo (delete the folder to fit it again). Installs what it needs, idempotently:
# libclang-dev (and pip), the ONNX Runtime library, the ImageNet weights, the release build.
#
#   scripts/demo.sh                      # 40 s; the page at http://127.0.0.1:8887/
#   scripts/demo.sh --seconds 300        # longer (any `jetpilot sim --realtime` options)
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-build-deps.sh --demo
ORT_DYLIB_PATH=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH
scripts/install-imagenet-weights.sh >/dev/null
cargo build --release --locked --quiet
BIN=target/release/jetpilot
CFG=config/sim.toml
DIR=.cache/demo
# The recipe: when it changes, the cached policy is fitted again.
RECIPE="scatter 600 + 600 random layouts; probe imagenet lite0 224 xy grid 2 mirror on"
if [ ! -f "$DIR/policy.onnx" ] || [ "$(cat "$DIR/recipe" 2>/dev/null)" != "$RECIPE" ]; then
  echo "demo: fitting the demo's policy (once; a few minutes)"
  rm -rf "$DIR/scatter" "$DIR/layouts" "$DIR/probe"
  mkdir -p "$DIR"
  "$BIN" -q sim --config "$CFG" --scatter 600 --record-xy "$DIR/scatter"
  "$BIN" -q sim --config "$CFG" --scatter 600 --random-layouts --record-xy "$DIR/layouts"
  "$BIN" -q train probe --config "$CFG" --data "$DIR/layouts" --data "$DIR/scatter" --init imagenet \
    --input-size 224 --head xy --grid 2 --mirror on -o "$DIR/probe"
  mv "$DIR/probe/probe.onnx" "$DIR/policy.onnx"
  echo "$RECIPE" >"$DIR/recipe"
fi
if [ $# -eq 0 ]; then set -- --seconds 40; fi
exec "$BIN" -q sim --config "$CFG" --model "$DIR/policy.onnx" --realtime --web --png "$DIR" "$@"
