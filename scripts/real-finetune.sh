#!/usr/bin/env bash
# Fine-tuning on real frames (docs/results/sim-to-real.md): `train il` on N real
# training frames spread evenly over the earlier 80 % by capture time, from a sim-pretrained
# model and from random weights, each scored
# on the latest 20 % (`jetpilot score --split-by-time 0.2`, the frames it never saw).
#
#   scripts/real-finetune.sh REALDATA INIT.onnx [OUT]
#       REALDATA: labelled JetBot frames (e.g. ../shared/realdata/jetbot_xy_mat)
#       INIT.onnx: the sim-pretrained xy model (e.g. .cache/s2r/matched/il/best.onnx);
#       "-" with STARTS of random and imagenet only
#
# Env: FRAMES (default "25 50 100 all"), IMAGES (real training images per run, default
# 3000: epochs = IMAGES / N, at least 10), STARTS (default "sim random"; `sim_mix` and
# `random_mix` also mix the folders of MIX (space-separated, relative to the repository),
# sim frames say, into every epoch with `train il --mix`, as MIX_SHARE of its images,
# default 0.5: such a run takes 1 / (1 - MIX_SHARE) times the steps; `imagenet` starts from
# the ImageNet EfficientNet-Lite0, `train il --init imagenet`, installing it with
# scripts/install-imagenet-weights.sh; IMAGENET_ARGS, default empty, are added to its runs,
# the fine-tuning recipe's flags), INPUT_SIZE (the
# network's input, default 96), BIN (skip the build), CFG (default config/sim.toml), IL_ARGS
# (more `train il` flags for every run, e.g. "--shift 0.25"), SEEDS (`train il --seed` of
# each run, default "$SEED", else 1; several, e.g. "1 2 3", repeat every run per seed).
# Each run is scored twice: its last epoch (last.onnx: a fixed budget of IMAGES) and the
# epoch `train il` picked as best (best.onnx: the lowest loss on its 10 % held out, 3 to 25
# near-duplicates of training frames here, so a noisy pick). Writes OUT/finetune.csv (one
# row per run: last_px, best_px), OUT/finetune.png (the last epochs' mean error against N,
# one line per start: the seeds' mean in a band of their sd), OUT/finetune_best.png (the
# same for the picked epochs), OUT/<start>_<N>/ (one seed) or OUT/<start>_<N>_s<seed>/
# (several). The CSVs of runs into separate OUTs (other seeds, say) can be appended with
# `cat` and drawn the same way with `jetpilot train plot` (it skips repeated headers).
# The real frames are linked, not copied, into OUT.
set -euo pipefail
cd "$(dirname "$0")/.."

REAL=${1:-}
INIT=${2:-}
OUT=${3:-.cache/real-finetune}
FRAMES=${FRAMES:-25 50 100 all}
IMAGES=${IMAGES:-3000}
STARTS=${STARTS:-sim random}
SEEDS=${SEEDS:-${SEED:-1}}
INPUT_SIZE=${INPUT_SIZE:-96}
if [ "$INIT" = - ] && [[ " $STARTS " != *" sim"* ]]; then
  INIT=/dev/null
fi
if [ -z "$REAL" ] || [ ! -d "$REAL" ] || [ -z "$INIT" ] || [ ! -e "$INIT" ]; then
  echo "usage: scripts/real-finetune.sh REALDATA INIT.onnx [OUT]: REALDATA must be a folder of" >&2
  echo "labelled JetBot frames (e.g. ../shared/realdata/jetbot_xy_mat) and INIT.onnx a model;" >&2
  echo "got '${REAL}' and '${INIT}'" >&2
  exit 2
fi
if [[ " $STARTS " = *_mix" "* ]]; then
  if [ -z "${MIX:-}" ]; then
    echo "STARTS has a *_mix start: set MIX to the folders to mix in (space-separated)" >&2
    exit 2
  fi
  for m in $MIX; do
    [ -d "$m" ] || { echo "MIX: no folder $m (paths are relative to the repository)" >&2; exit 2; }
  done
fi
REAL=$(cd "$REAL" && pwd)
INIT=$(cd "$(dirname "$INIT")" && pwd)/$(basename "$INIT")

if [[ " $STARTS " = *" imagenet"* ]]; then
  scripts/install-imagenet-weights.sh > /dev/null
fi
. scripts/lib/binary.sh
. scripts/lib/frames.sh
jetpilot_binary --features train
mkdir -p "$OUT"

frames_by_time "$REAL" "$OUT/by_time.txt"
TOTAL=$(wc -l < "$OUT/by_time.txt")
TRAIN=$(earlier "$TOTAL")
echo "real frames: $TOTAL, the earliest $TRAIN to train on, the rest scored"

echo "frames,start,seed,last_px,best_px,baseline_px,epochs" > "$OUT/finetune.csv"
read -r -a seeds <<< "$SEEDS"
for n in $FRAMES; do
  [ "$n" = all ] && n=$TRAIN
  d="$OUT/frames_$n"
  link_spread "$n" "$TRAIN" "$OUT/by_time.txt" "$d"
  got=$(find "$d" -name '*.jpg' | wc -l)
  epochs=$(( IMAGES / got ))
  [ "$epochs" -lt 10 ] && epochs=10
  for start in $STARTS; do
    for seed in "${seeds[@]}"; do
      r="$OUT/${start}_$n"
      [ "${#seeds[@]}" -gt 1 ] && r="${r}_s$seed"
      rm -rf "$r"
      start_args=()
      [[ "$start" = sim* ]] && start_args=(--init "$INIT")
      # shellcheck disable=SC2206 # IMAGENET_ARGS is a list of words
      [[ "$start" = imagenet* ]] && start_args=(--init imagenet ${IMAGENET_ARGS:-})
      if [[ "$start" = *_mix ]]; then
        for m in $MIX; do start_args+=(--mix "$m"); done
        start_args+=(--mix-share "${MIX_SHARE:-0.5}")
      fi
      echo "== $start start, $got real frames, $epochs epochs, seed $seed"
      # shellcheck disable=SC2086 # IL_ARGS is a list of words
      "$B" train il --config "${CFG:-config/sim.toml}" --input-size "$INPUT_SIZE" --head xy \
        --epochs "$epochs" --seed "$seed" "${start_args[@]}" ${IL_ARGS:-} --data "$d" --out "$r" \
        > "$r.log" 2>&1
      for ckpt in last best; do
        "$B" score --model "$r/$ckpt.onnx" --data "$REAL" --split-by-time 0.2 \
          --out "$r/score_$ckpt" > "$r/score_$ckpt.txt"
      done
      last=$(mean model "$r/score_last.txt")
      best=$(mean model "$r/score_best.txt")
      base=$(mean baseline "$r/score_last.txt")
      echo "   mean error: last epoch $last px, picked epoch $best px (baseline $base px)"
      echo "$got,$start,$seed,$last,$best,$base,$epochs" >> "$OUT/finetune.csv"
    done
  done
done
"$B" train plot --csv "$OUT/finetune.csv" --x frames --y last_px --series start \
  --title "real frames: mean error against training frames (last epoch)" --out "$OUT/finetune.png"
"$B" train plot --csv "$OUT/finetune.csv" --x frames --y best_px --series start \
  --title "real frames: mean error against training frames (picked epoch)" \
  --out "$OUT/finetune_best.png"
cat "$OUT/finetune.csv"
