#!/usr/bin/env bash
# Speed and memory of the two networks (issue 48, 5c): ResNet-18 (random weights: speed does
# not depend on them) and the ImageNet EfficientNet-Lite0 (`model import`), at each input
# size, fp32 and int8, through `jetpilot bench --model`: bare ONNX Runtime `session.run`
# and the daemon's frame -> motor command path end to end (preprocessing, inference, the
# steering law and the PCA9685 encoding), each as median and p90 over ITERATIONS.
#
#   scripts/backbone-bench.sh OUT [CALIBRATION_DIR]
#
# int8 copies are calibrated on CALIBRATION_DIR (a JetBot xy folder; default ../shared/realdata/jetbot_xy_mat) with
# `--tolerance 1000`: this measures speed only; whether an int8 copy keeps its accuracy is
# `model quantize`'s own check (docs/results/int8.md). Env: SIZES (default "96 128 160
# 224"), ITERATIONS (200), THREADS (2), BIN (default: a release build).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: scripts/backbone-bench.sh OUT [CALIBRATION_DIR]}
CAL=${2:-../shared/realdata/jetbot_xy_mat}
SIZES=${SIZES:-96 128 160 224}
ITERATIONS=${ITERATIONS:-200}
THREADS=${THREADS:-2}
ORT_DYLIB_PATH=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH
PTH=$(scripts/install-imagenet-weights.sh)
if [ -z "${BIN:-}" ]; then
  cargo build --release --locked --quiet
  BIN=target/release/jetpilot
fi
mkdir -p "$OUT"
models=()
for s in $SIZES; do
  "$BIN" -q model init --arch resnet18 --input-size "$s" --head xy -o "$OUT/resnet18_$s.onnx"
  "$BIN" -q model import "$PTH" --arch efficientnet-lite0 --input-size "$s" --head xy -o "$OUT/lite0_$s.onnx"
  for net in resnet18 lite0; do
    "$BIN" -q model quantize "$OUT/${net}_$s.onnx" --calibration "$CAL" --tolerance 1000 \
      -o "$OUT/${net}_${s}_int8.onnx"
    models+=(--model "$OUT/${net}_$s.onnx" --model "$OUT/${net}_${s}_int8.onnx")
  done
done
"$BIN" bench "${models[@]}" --iterations "$ITERATIONS" --threads "$THREADS" --paced-seconds 0 \
  --json "$OUT/bench.json" | tee "$OUT/bench.txt"
