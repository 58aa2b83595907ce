#!/usr/bin/env bash
# int8 against float32 (README, "int8"): for each input size, an imitation policy from the
# same demonstrations and seed, its int8 copy from `jetpilot model quantize`, then
#   - latency and peak RSS: `jetpilot bench --model FP32 --model INT8`, twice, in both
#     orders (ONNX Runtime's CPU provider, 2 intra-op threads);
#   - driving: `jetpilot eval`, 600 s on the default mat, both models;
#   - the output difference on held-out frames (printed by `model quantize`).
# With REALDATA (e.g. ../shared/realdata/jetbot_xy_mat) it also trains the sim-to-real
# "matched" xy policy (scripts/sim-to-real.sh), quantizes it calibrated on the earlier 80 %
# of the real frames, and scores both on the latest 20 % (`score --split-by-time 0.2`).
#
#   scripts/int8-study.sh [OUT] [REALDATA]     (default OUT: .cache/int8)
#
# SIZES (default "96"), EPOCHS (default 50, README's recipe), EVAL_S (default 600),
# BIN (a built jetpilot: no build). Everything goes to OUT/*.log; the summary to stdout.
set -euo pipefail
cd "$(dirname "$0")/.."

OUT=${1:-.cache/int8}
REAL=${2:-}
SIZES=${SIZES:-96}
EPOCHS=${EPOCHS:-50}
EVAL_S=${EVAL_S:-600}
CFG=config/sim.toml

ORT_LIB=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH="$ORT_LIB"
if [ -n "${BIN:-}" ]; then
  B=$BIN
else
  scripts/install-build-deps.sh
  cargo build --release --features train --locked
  B=target/release/jetpilot
fi
mkdir -p "$OUT"

# README's demonstrations: 331 frames over about 1.2 laps of the default mat, with recoveries.
if [ ! -d "$OUT/demos" ]; then
  $B sim --config "$CFG" --expert --seconds 60 --swerve-every 3 --record-every 3 \
    --record-frames 331 --record "$OUT/demos" > "$OUT/demos.log"
fi

for s in $SIZES; do
  d="$OUT/il_$s"
  echo "== $s x $s"
  if [ ! -f "$d/best.onnx" ]; then
    $B train il --config "$CFG" --input-size "$s" --head speed-steering --epochs "$EPOCHS" \
      --seed 0 --data "$OUT/demos" --out "$d" > "$OUT/il_$s.log" 2>&1
  fi
  $B model quantize "$d/best.onnx" -o "$d/int8.onnx" --calibration "$OUT/demos" \
    | tee "$OUT/quantize_$s.log"
  for order in "best int8" "int8 best"; do
    read -r first second <<< "$order"
    $B -q bench --model "$d/$first.onnx" --model "$d/$second.onnx" --paced-seconds 0 \
      --iterations 200 --warmup 20 > "$OUT/bench_${s}_$first-first.log"
    grep -E 'model|session.run|end to end|VmHWM|peak' "$OUT/bench_${s}_$first-first.log" || true
  done
  for m in best int8; do
    $B eval --config "$CFG" --model "$d/$m.onnx" --seconds "$EVAL_S" --json "$OUT/eval_${s}_$m.json" \
      > "$OUT/eval_${s}_$m.log"
    echo "eval $s $m: $(tr -d '\n' < "$OUT/eval_${s}_$m.json" | cut -c1-300)"
  done
done

if [ -n "$REAL" ]; then
  echo "== real frames: the matched xy policy"
  if [ ! -f "$OUT/s2r/matched/il/best.onnx" ]; then
    BIN=$B VARIANTS=matched scripts/sim-to-real.sh "$REAL" "$OUT/s2r" > "$OUT/s2r.log" 2>&1
  fi
  m="$OUT/s2r/matched/il"
  # Calibrate on real frames: the latest 20 % by capture time are held out (and scored).
  $B model quantize "$m/best.onnx" -o "$m/int8.onnx" --calibration "$REAL" --holdout 0.2 \
    | tee "$OUT/quantize_xy.log"
  for n in best int8; do
    $B score --model "$m/$n.onnx" --data "$REAL" --split-by-time 0.2 --out "$OUT/score_$n" \
      | tee "$OUT/score_$n.log" | grep -E 'model|baseline' || true
  done
fi
