#!/usr/bin/env bash
# LP-FT on real frames (docs/results/pretrained-backbones.md, "LP-FT"): a linear probe of
# the frozen ImageNet EfficientNet-Lite0 (`train probe`), then a fine-tune of the whole
# network from it (`train il --init probe.onnx`), its setting chosen without the test frames.
#
#   scripts/lp-ft.sh REALDATA [OUT]
#       REALDATA: labelled JetBot frames (e.g. ../shared/realdata/jetbot_xy_carpet)
#
# The frames are sorted by capture time. The latest 20 % are the test frames (`jetpilot
# score --split-by-time 0.2`); nothing is chosen on them. The earlier 80 % are split the
# same way: their earliest 80 % fit, their latest 20 % choose.
# 1. Selection: a probe on the selection's fitting frames; each of CANDIDATES fine-tunes
#    from it; the probe and every fine-tune are scored on the selection's latest frames.
# 2. Test: the candidate with the lowest selection error is run again on the whole earlier
#    80 % (a new probe, then the fine-tune); the probe and the fine-tune are scored on the
#    test frames.
#
# Env: CANDIDATES (the `train il` flags of each fine-tune, separated by ';', default
# "--lr 1e-4;--lr 1e-5"), EPOCHS (default 10), INPUT_SIZE (default 224), SEED (default 1),
# TEST_SEEDS (more seeds, separated by spaces, for the test's fine-tune: each is run from the
# test's probe and gets its own row; so does the ensemble of all the seeds' models, `model
# ensemble`), PROBE_DATA (more labelled folders, separated by spaces, that both probes fit
# on beside REALDATA's own frames, e.g. the other real set; the fine-tunes and scores use
# REALDATA only), BIN (skip the build). PROBE_DATA may list alternatives separated by ';',
# '-' for REALDATA's frames alone (e.g. "-;MAT;MAT SIM"): the selection then fits one probe
# per alternative, runs every candidate from each, and the lowest fine-tune row picks the
# alternative and the candidate together; the rows are named with the alternative's
# folders (their base names joined by '+', "own" for '-').
# Every fine-tune has --freeze-bn and --head xy, and is scored at its last epoch. Writes
# OUT/selection.csv (candidate, px, baseline_px), OUT/test.csv (model, px, baseline_px,
# x_corr), OUT/sel/ and OUT/test/ (the models, logs and scores; OUT/sel/poolK/ for the
# K-th alternative). The real frames are linked, not copied.
set -euo pipefail
cd "$(dirname "$0")/.."

REAL=${1:-}
OUT=${2:-.cache/lp-ft}
CANDIDATES=${CANDIDATES:---lr 1e-4;--lr 1e-5}
EPOCHS=${EPOCHS:-10}
INPUT_SIZE=${INPUT_SIZE:-224}
SEED=${SEED:-1}
PROBE_DATA=${PROBE_DATA:-}
TEST_SEEDS=${TEST_SEEDS:-}
if [ -z "$REAL" ] || [ ! -d "$REAL" ]; then
  echo "usage: scripts/lp-ft.sh REALDATA [OUT]: REALDATA must be a folder of labelled" >&2
  echo "JetBot frames (e.g. ../shared/realdata/jetbot_xy_carpet); got '${REAL}'" >&2
  exit 2
fi
REAL=$(cd "$REAL" && pwd)
# PROBE_DATA's alternatives; each folder is checked before anything runs.
IFS=';' read -r -a pools <<< "$PROBE_DATA"
[ ${#pools[@]} -gt 0 ] || pools=("")
for alt in "${pools[@]}"; do
  for d in $alt; do
    [ "$d" = - ] || [ -d "$d" ] || { echo "PROBE_DATA: '$d' is not a folder" >&2; exit 2; }
  done
done
# use_pool ALT: sets `extra` (ALT's folders as `--data DIR` pairs) and `pool_label`.
use_pool() {
  extra=()
  pool_label=
  local d
  for d in $1; do
    [ "$d" != - ] || continue
    extra+=(--data "$(cd "$d" && pwd)")
    pool_label+=${pool_label:++}$(basename "$d")
  done
  pool_label=${pool_label:-own}
}
# A row's name gains " (probe data: LABEL)" only where there are alternatives to tell apart.
named() {
  if [ ${#pools[@]} -gt 1 ]; then echo "$1 (probe data: $pool_label)"; else echo "$1"; fi
}
for alt in "${pools[@]}"; do
  use_pool "$alt"
  [ ${#extra[@]} -eq 0 ] || echo "the probes also fit on: $alt"
done
scripts/install-imagenet-weights.sh > /dev/null
. scripts/lib/binary.sh
. scripts/lib/frames.sh
jetpilot_binary --features train
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

frames_by_time "$REAL" "$OUT/by_time.txt"
# The x correlation (labels against predictions) of `score`'s tracking line.
xcorr() { sed -n 's/^ *tracking .*correlation (\([-+0-9.]*\),.*/\1/p' "$1"; }
TOTAL=$(wc -l < "$OUT/by_time.txt")
TRAIN=$(earlier "$TOTAL")
FIT=$(earlier "$TRAIN")
echo "real frames: $TOTAL; selection: fit on the earliest $FIT, choose on the next $((TRAIN - FIT));"
echo "test: fit on the earliest $TRAIN, score the latest $((TOTAL - TRAIN))"
link_first "$TRAIN" "$OUT/by_time.txt" "$OUT/frames_train"
link_first "$FIT" "$OUT/by_time.txt" "$OUT/frames_fit"

# failed WHAT LOG: says which step failed and the end of its log, and stops.
failed() {
  echo "$1 failed; the end of $2:" >&2
  tail -n 5 "$2" >&2
  exit 1
}
# probe FRAMES DIR: the probe of FRAMES (and the alternative's folders, `extra`) into DIR/probe.
probe() {
  "$B" train probe --init imagenet --input-size "$INPUT_SIZE" --head xy --data "$1" \
    "${extra[@]}" -o "$2/probe" > "$2/probe.log" 2>&1 || failed "train probe" "$2/probe.log"
}
# finetune ARGS FRAMES DIR NAME [SEED]: the fine-tune from DIR/probe into DIR/NAME.
finetune() {
  # shellcheck disable=SC2086 # ARGS is a list of words
  "$B" train il --init "$3/probe/probe.onnx" --input-size "$INPUT_SIZE" --head xy \
    --freeze-bn true --epochs "$EPOCHS" --seed "${5:-$SEED}" $1 --data "$2" --out "$3/$4" \
    > "$3/$4.log" 2>&1 || failed "train il $1" "$3/$4.log"
}
# scored MODEL DATA OUTFILE: `score`'s text for MODEL on DATA's latest 20 %.
scored() {
  "$B" score --model "$1" --data "$2" --split-by-time 0.2 --out "${3%.txt}" > "$3" 2>&1 \
    || failed "score $1" "$3"
}

echo "== selection"
S="$OUT/sel"
mkdir -p "$S"
echo "candidate,px,baseline_px" > "$OUT/selection.csv"
IFS=';' read -r -a candidates <<< "$CANDIDATES"
best=
best_px=
best_pool=
for k in "${!pools[@]}"; do
  use_pool "${pools[$k]}"
  # One alternative keeps the layout of old runs: OUT/sel/probe, OUT/sel/ft0, ...
  D=$S
  [ ${#pools[@]} -eq 1 ] || D="$S/pool$k"
  mkdir -p "$D"
  probe "$OUT/frames_fit" "$D"
  scored "$D/probe/probe.onnx" "$OUT/frames_train" "$D/probe_score.txt"
  f="$D/probe_score.txt"
  echo "\"$(named "probe alone")\",$(mean model "$f"),$(mean baseline "$f")" \
    | tee -a "$OUT/selection.csv"
  for i in "${!candidates[@]}"; do
    args=${candidates[$i]}
    finetune "$args" "$OUT/frames_fit" "$D" "ft$i"
    scored "$D/ft$i/last.onnx" "$OUT/frames_train" "$D/ft${i}_score.txt"
    px=$(mean model "$D/ft${i}_score.txt")
    echo "\"$(named "fine-tune $args")\",$px,$(mean baseline "$D/ft${i}_score.txt")" \
      | tee -a "$OUT/selection.csv"
    if [ -z "$best_px" ] || awk -v a="$px" -v b="$best_px" 'BEGIN { exit !(a < b) }'; then
      best=$args
      best_px=$px
      best_pool=$k
    fi
  done
done
use_pool "${pools[$best_pool]}"
echo "chosen: $(named "fine-tune $best") ($best_px px on the selection)"

echo "== test"
T="$OUT/test"
mkdir -p "$T"
probe "$OUT/frames_train" "$T"
finetune "$best" "$OUT/frames_train" "$T" ft
# NAME|MODEL pairs (a name may hold ':', "probe data: own").
models=("$(named "probe alone")|$T/probe/probe.onnx")
models+=("$(named "fine-tune $best")|$T/ft/last.onnx")
members=("$T/ft/last.onnx")
for s in $TEST_SEEDS; do
  finetune "$best" "$OUT/frames_train" "$T" "ft_seed$s" "$s"
  models+=("$(named "fine-tune $best") (seed $s)|$T/ft_seed$s/last.onnx")
  members+=("$T/ft_seed$s/last.onnx")
done
# With more seeds, their ensemble too: one file that answers the mean of the seeds' answers.
if [ ${#members[@]} -gt 1 ]; then
  "$B" model ensemble "${members[@]}" -o "$T/ensemble.onnx" > "$T/ensemble.log" 2>&1 \
    || failed "model ensemble" "$T/ensemble.log"
  seeds=$(echo "$SEED" $TEST_SEEDS)
  models+=("$(named "fine-tune $best") (ensemble of seeds $seeds)|$T/ensemble.onnx")
fi
echo "model,px,baseline_px,x_corr" > "$OUT/test.csv"
for m in "${models[@]}"; do
  name=${m%%|*}
  f=${name//[ \/]/_}
  f="$T/${f}_score.txt"
  scored "${m#*|}" "$REAL" "$f"
  echo "\"$name\",$(mean model "$f"),$(mean baseline "$f"),$(xcorr "$f")" \
    | tee -a "$OUT/test.csv"
done
echo "wrote $OUT/selection.csv and $OUT/test.csv"
