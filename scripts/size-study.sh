#!/usr/bin/env bash
# Input size x precision (docs/results/input-size.md and docs/results/int8.md): for each input size, an imitation
# policy from the same demonstrations, recipe and seed, and its int8 copy from
# `jetpilot model quantize`, then
#   - driving: `jetpilot eval`, EVAL_S on the default mat, both models;
#   - the output difference on held-out frames (printed by `model quantize`);
#   - with REALDATA (e.g. ../shared/realdata/jetbot_xy_mat): an xy policy at the same size
#     trained on the earlier 80 % of the real frames by capture time from random weights
#     (scripts/real-finetune.sh, all frames, IMAGES images), its int8 copy calibrated on
#     those frames, both scored on the latest 20 % (`score --split-by-time 0.2`);
# and, once every size is trained:
#   - latency: one `jetpilot bench` over every model (bare `session.run`, end to end, CPU %
#     paced at 15 fps), run twice, the second time in the reverse order;
#   - memory: the daemon's peak RSS (`/usr/bin/time -f %M jetpilot -q run --duration 4`)
#     on config/demo.toml with each model, three runs each.
# Only the imitation models are benched and measured for memory (an xy model of the same
# size costs the same). MATCHED=1 also quantizes the sim-to-real "matched" xy policy (scripts/sim-to-real.sh,
# 96x96), calibrated on the earlier 80 % of the real frames, and scores both on the rest.
#
#   scripts/size-study.sh [OUT] [REALDATA]     (default OUT: .cache/sizes)
#
# SIZES (default "96 112 160 224"), EPOCHS (default 50: the paper's recipe; at 20 the 224
# and 160 policies drove the mat's corners within a few cm of the edge), EVAL_S (default 600), IMAGES
# (default 3000), BIN (a built jetpilot: no build), CFG (default config/sim.toml; a copy in
# an older BIN's format when BIN is older than the tree). A step whose output exists is skipped,
# so an interrupted study goes on where it stopped. Logs in OUT/*.log; OUT/summary.txt.
set -euo pipefail
cd "$(dirname "$0")/.."

OUT=${1:-.cache/sizes}
REAL=${2:-}
SIZES=${SIZES:-96 112 160 224}
EPOCHS=${EPOCHS:-50}
EVAL_S=${EVAL_S:-600}
IMAGES=${IMAGES:-3000}
CFG=${CFG:-config/sim.toml}   # a copy in the format of an older BIN, if BIN is older
if [ -n "$REAL" ] && [ ! -d "$REAL" ]; then
  echo "scripts/size-study.sh: REALDATA '$REAL' is not a folder of labelled JetBot frames" >&2
  exit 2
fi

[ -x /usr/bin/time ] || scripts/install-build-deps.sh   # GNU time, for the peak RSS
. scripts/lib/binary.sh
jetpilot_binary --features train
mkdir -p "$OUT"

# The training recipe's demonstrations (docs/guides/training.md): 331 frames over about 1.2 laps of the default mat, with recoveries.
if [ ! -d "$OUT/demos" ]; then
  $B sim --config "$CFG" --expert --seconds 60 --swerve-every 3 --record-every 3 \
    --record-frames 331 --record "$OUT/demos" > "$OUT/demos.log"
fi

models=()
for s in $SIZES; do
  d="$OUT/il_$s"
  echo "== $s x $s"
  done_epochs=0
  [ -f "$d/il_state.json" ] && done_epochs=$(grep -o '"epochs_done": *[0-9]*' "$d/il_state.json" | grep -o '[0-9]*$')
  if [ "$done_epochs" -lt "$EPOCHS" ] && [ -f "$d/best.onnx" ]; then
    # Trained for fewer epochs than asked: train on (--resume gives the losses of an unbroken
    # run) and measure this size's imitation models again.
    echo "il $s: $done_epochs of $EPOCHS epochs done, training on"
    rm -f "$OUT/quantize_$s.log" "$OUT/eval_${s}_best.json" "$OUT/eval_${s}_int8.json" "$d/int8.onnx"
  fi
  if [ ! -f "$d/best.onnx" ] || [ ! -f "$OUT/quantize_$s.log" ]; then
    resume=()
    [ -f "$d/il_state.json" ] && resume=(--resume)
    $B train il --config "$CFG" --input-size "$s" --head speed-steering --epochs "$EPOCHS" \
      --seed 0 --data "$OUT/demos" --out "$d" "${resume[@]}" >> "$OUT/il_$s.log" 2>&1
    # A refusal (--tolerance) is reported, and the study goes on without that int8 model.
    $B model quantize "$d/best.onnx" -o "$d/int8.onnx" --calibration "$OUT/demos" \
      > "$OUT/quantize_$s.log" 2>&1 || echo "int8 $s: refused or failed, see $OUT/quantize_$s.log"
  fi
  grep -E 'held-out|QLinearConv|refused' "$OUT/quantize_$s.log" || true
  for m in best int8; do
    [ -f "$d/$m.onnx" ] || continue
    models+=("$d/$m.onnx")
    if [ ! -f "$OUT/eval_${s}_$m.json" ]; then
      $B -q eval --config "$CFG" --model "$d/$m.onnx" --seconds "$EVAL_S" \
        --json "$OUT/eval_${s}_$m.json.part" > "$OUT/eval_${s}_$m.log"
      mv "$OUT/eval_${s}_$m.json.part" "$OUT/eval_${s}_$m.json"
    fi
    echo "eval $s $m: $(grep -E '"(interventions|autonomy_percent|rewards|laps)"' \
      "$OUT/eval_${s}_$m.json" | tr -d ' \n')"
  done
  if [ -n "$REAL" ]; then
    r="$OUT/real_$s"
    if ! ls "$r"/random_*/score_best.txt > /dev/null 2>&1; then
      FRAMES=all STARTS=random INPUT_SIZE=$s BIN=$B scripts/real-finetune.sh "$REAL" - "$r" \
        > "$OUT/real_$s.log" 2>&1
      rm -f "$r"/random_*/il_optim.bpk
    fi
    if [ ! -f "$r/score_int8.txt" ]; then
      m=$(ls -d "$r"/random_*/ | head -1)
      if $B model quantize "$m/best.onnx" -o "$r/random_int8.onnx" --calibration "$REAL" \
        --holdout 0.2 > "$OUT/quantize_real_$s.log" 2>&1; then
        $B -q score --model "$r/random_int8.onnx" --data "$REAL" --split-by-time 0.2 \
          --out "$r/score_int8" > "$r/score_int8.txt"
      else
        echo "real int8 $s: refused or failed, see $OUT/quantize_real_$s.log"
      fi
    fi
    for f in "$r"/random_*/score_best.txt "$r/score_int8.txt"; do
      [ -f "$f" ] || continue
      echo "real $s $f: $(awk '$1 == "model" && $2 == "mean"' "$f") $(grep 'model / baseline' "$f")"
    done
  fi
done

if [ -n "$REAL" ] && [ "${MATCHED:-0}" = 1 ]; then
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

echo "== latency and CPU (bench, every model, both orders)"
args=()
for m in "${models[@]}"; do args+=(--model "$m"); done
$B -q bench "${args[@]}" --paced-seconds 4 --paced-fps 15 --iterations 200 --warmup 20 \
  > "$OUT/bench_forward.log"
rev=()
for ((i = ${#args[@]} - 1; i > 0; i -= 2)); do rev+=(--model "${args[i]}"); done
$B -q bench "${rev[@]}" --paced-seconds 4 --paced-fps 15 --iterations 200 --warmup 20 \
  > "$OUT/bench_reverse.log"
for f in "$OUT/bench_forward.log" "$OUT/bench_reverse.log"; do
  grep -E '^[0-9]+x[0-9]+  [^m]|bare ort run|end to end|15 fps' "$f" || true
done

echo "== daemon peak RSS (config/demo.toml, 4 s, three runs each)"
for m in "${models[@]}"; do
  abs=$(cd "$(dirname "$m")" && pwd)/$(basename "$m")
  sed "s|^path = .*\.onnx\"|path = \"$abs\"|; s|^path = \"samples/road\"|path = \"$PWD/config/samples/road\"|
    s|^print_commands = .*|print_commands = false|" config/demo.toml > "$OUT/demo_rss.toml"
  kib=()
  for _ in 1 2 3; do
    if /usr/bin/time -f %M -o "$OUT/rss.txt" $B -q run --config "$OUT/demo_rss.toml" \
      --duration 4 > "$OUT/rss_run.log" 2>&1; then
      kib+=("$(tail -1 "$OUT/rss.txt")")
    else
      kib+=("failed($(tail -1 "$OUT/rss_run.log"))")
    fi
  done
  echo "rss $m: ${kib[*]} KiB"
done
