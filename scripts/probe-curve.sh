#!/usr/bin/env bash
# The linear probe's curve on real frames (docs/results/pretrained-backbones.md, "Linear
# probe"): `jetpilot train probe` (ImageNet EfficientNet-Lite0, frozen; its head fitted by
# ridge regression, grid and mirroring chosen by cross-validation on the training frames)
# on N frames spread evenly over the earlier 80 % by capture time, each scored on the
# latest 20 % (`jetpilot score --split-by-time 0.2`), which no run sees.
#
#   scripts/probe-curve.sh REALDATA [OUT]
#       REALDATA: labelled JetBot frames (e.g. ../shared/realdata/jetbot_xy_mat)
#
# Env: FRAMES (default "25 50 100 all"), INPUT_SIZE (default 224), PROBE_ARGS (more
# `train probe` flags, e.g. "--grid 1 --mirror off"), BIN (skip the build). Writes
# OUT/probe_curve.csv (frames, px, baseline_px, pooling) and OUT/probe_<N>/ (the model,
# its cross-validation table, its score). The real frames are linked, not copied.
set -euo pipefail
cd "$(dirname "$0")/.."

REAL=${1:-}
OUT=${2:-.cache/probe-curve}
FRAMES=${FRAMES:-25 50 100 all}
INPUT_SIZE=${INPUT_SIZE:-224}
if [ -z "$REAL" ] || [ ! -d "$REAL" ]; then
  echo "usage: scripts/probe-curve.sh REALDATA [OUT]: REALDATA must be a folder of labelled" >&2
  echo "JetBot frames (e.g. ../shared/realdata/jetbot_xy_mat); got '${REAL}'" >&2
  exit 2
fi
REAL=$(cd "$REAL" && pwd)
scripts/install-imagenet-weights.sh > /dev/null
. scripts/lib/binary.sh
. scripts/lib/frames.sh
jetpilot_binary --features train
mkdir -p "$OUT"

frames_by_time "$REAL" "$OUT/by_time.txt"
TOTAL=$(wc -l < "$OUT/by_time.txt")
TRAIN=$(earlier "$TOTAL")
echo "real frames: $TOTAL, the earliest $TRAIN to fit on, the rest scored"

echo "frames,px,baseline_px,pooling" > "$OUT/probe_curve.csv"
for n in $FRAMES; do
  [ "$n" = all ] && n=$TRAIN
  d="$OUT/frames_$n"
  link_spread "$n" "$TRAIN" "$OUT/by_time.txt" "$d"
  got=$(find "$d" -name '*.jpg' | wc -l)
  r="$OUT/probe_$n"
  rm -rf "$r"
  echo "== probe on $got real frames"
  folds=5
  [ "$got" -lt 50 ] && folds=3
  # shellcheck disable=SC2086 # PROBE_ARGS is a list of words
  "$B" train probe --init imagenet --input-size "$INPUT_SIZE" --head xy --folds "$folds" \
    ${PROBE_ARGS:-} --data "$d" -o "$r" > "$r.log" 2>&1
  pooling=$(grep ' -> ' "$r.log" | tail -1 | sed 's/ -> .*//')   # "grid 2x2, ..., ridge strength S" or "the mean label"
  "$B" score --model "$r/probe.onnx" --data "$REAL" --split-by-time 0.2 --out "$r/score" \
    > "$r/score.txt" 2>&1
  echo "$got,$(mean model "$r/score.txt"),$(mean baseline "$r/score.txt"),\"$pooling\"" \
    | tee -a "$OUT/probe_curve.csv"
done
echo "wrote $OUT/probe_curve.csv"
