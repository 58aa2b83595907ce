#!/usr/bin/env bash
# The paper's pipeline end to end in the simulator, as measured in docs/results/trainer-end-to-end.md:
# 331 scripted-expert demonstrations with recoveries -> imitation learning (50 epochs) -> DDPG from the
# imitation policy plus the demonstrations, for what is left of a wall-clock budget
# (TRAIN_MINUTES, default 30) -> the paper's 600 s evaluation of the best policy.
#   scripts/train-e2e.sh [OUT]              (default OUT: .cache/e2e)
#   SCRATCH=1 scripts/train-e2e.sh OUT      DDPG from scratch (random actor, no
#                                           demonstrations) for the whole budget
# CAMERA (default pinhole: the 120-degree pinhole the numbers in docs/results/ used; jetbot for JetBot's
# fisheye, the config's default) picks the simulated camera.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-build-deps.sh
ORT_LIB=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH="$ORT_LIB"
cargo build --release --features train --locked
B=target/release/jetpilot
OUT=${1:-.cache/e2e}
MINUTES=${TRAIN_MINUTES:-30}
CFG=config/sim.toml
CAM=(--camera "${CAMERA:-pinhole}")
rm -rf "$OUT"
mkdir -p "$OUT"
start=$(date +%s)
if [ "${SCRATCH:-0}" = 1 ]; then
  $B train ddpg --sim "$CFG" "${CAM[@]}" --out "$OUT/ddpg" --minutes "$MINUTES"
else
  # 331 frames over about 1.2 laps (every 3rd control step, 10 per second), recording
  # paused during the expert's swerves so the frames include recoveries.
  $B sim --config "$CFG" "${CAM[@]}" --expert --seconds 60 --swerve-every 3 --record-every 3 \
    --record-frames 331 --record "$OUT/demos"
  $B train il --config "$CFG" --input-size 96 --head speed-steering \
    --data "$OUT/demos" --out "$OUT/il"
  left=$(awk -v m="$MINUTES" -v s="$(( $(date +%s) - start ))" 'BEGIN { printf "%.2f", m - s / 60 }')
  $B train ddpg --sim "$CFG" "${CAM[@]}" --init "$OUT/il/best.onnx" --demos "$OUT/demos" \
    --out "$OUT/ddpg" --minutes "$left"
fi
echo "wall time: $(( $(date +%s) - start )) s"
$B eval --config "$CFG" "${CAM[@]}" --model "$OUT/ddpg/best.onnx" --json "$OUT/eval.json" --png "$OUT/trace.png"
