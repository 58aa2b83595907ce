#!/usr/bin/env bash
# A real recording becomes a simulator, end to end (issue 49 item 3,
# docs/results/real-replay.md):
#
#   scripts/real-replay.sh TUB OUT
#
# 1. `jetpilot poses` on TUB (a DonkeyCar tub: config/donkeycar.toml, the car-like prior;
#    a tub with wheels/left, wheels/right: the JetBot defaults, or CONFIG=FILE), with
#    --check-views and --turn-from-loops: OUT/poses/ is the tub with poses, its trace
#    (poses.png), the view check (check-views.csv, .png) and replay.toml. A car's replay
#    drives the calibrated car (sim.vehicle = "car").
# 2. The recording is split by time: the earlier 1 - SPLIT (default SPLIT 0.3) is the
#    training part, the latest SPLIT the held-out part. The held-out part's first SELECT
#    (default 0.15 of the whole recording) is the selection part, where DDPG's evaluations
#    run and pick best.onnx; the rest of it is the report part that nothing is chosen on.
#    OUT/poses/early.toml, middle.toml and late.toml are replay.toml with
#    `sim.recording_span` set to each: their own frames, their own road. SELECT=0: no
#    middle part, DDPG picks best.onnx on the early replay (the two-part split of the
#    script before commit de3f0cc).
# 3. Imitation on the training part's frames, speed_steering, and `score` on the held-out
#    frames. IL=probe (the default): `train probe` (the frozen ImageNet EfficientNet-Lite0 at
#    224, its output layer fitted in closed form, 1x1 pooled so `train ddpg --init` takes
#    it). IL=finetune: `train il --init imagenet` (the whole Lite0 fine-tuned at 96x96 with
#    the pretrained starts' recipe, IL_EPOCHS epochs, default 10, seeded by SEED;
#    `--leave-latest SPLIT` keeps the held-out frames out), about 5 minutes more.
# 4. `eval` (EVAL_SECONDS, default 120) on every part's replay of the scripted expert at the
#    recording's mean speed (the bar: is the replay drivable?) and of the imitation policy;
#    `train ddpg`
#    (MINUTES, default 10) against the early replay from it; `eval` of DDPG's last.onnx and
#    best.onnx on every part (best is picked on the middle replay's evaluations, so the late
#    replay is the held-out check of both).
#    DDPG's demonstrations (DEMOS=expert, the default): the scripted expert drives the early
#    replay for 60 s with a swerve every 3 s on average, and only its ways back are
#    recorded, every third control step (OUT/demos, with the replay's rewards): recovery
#    demonstrations of the training part, which a human's tub lacks (it has neither swerves
#    nor rewards). DEMOS=none runs DDPG without. DDPG_FLAGS are `train ddpg`'s flags
#    beyond these; the default is the recipe chosen on the early replay
#    (docs/results/real-replay.md, "DDPG on the replay"): policy improvement by search, the
#    anchor to the imitation policy kept, half the episodes started before an earlier
#    failure, OU noise on the steering. DDPG_FLAGS= (empty) runs `train ddpg`'s own
#    defaults.
# 5. OUT/report.md: the poses' lines, the view check, the score, the eval table and DDPG's
#    evaluations during training (start, median, range) and its critic's mean Q.
#
# DDPG_EVAL_SECONDS (default 60): the length of DDPG's own evaluations during training
# (every 10 episodes, on the middle replay; the early one with SELECT=0), which pick
# best.onnx.
# BIN skips the build (it needs the `train` feature). SEED (default 0) seeds DDPG. About
# 15 minutes on 2 cores with the defaults. The real frames stay under OUT: never commit it.
set -euo pipefail

TUB=${1:-}
OUT=${2:-}
# Relative paths are the caller's: made absolute before the script moves to the repository.
abs() { case "$1" in /*) echo "$1" ;; *) echo "$PWD/$1" ;; esac; }
[ -n "$TUB" ] && TUB=$(abs "$TUB")
[ -n "$OUT" ] && OUT=$(abs "$OUT")
[ -n "${CONFIG:-}" ] && CONFIG=$(abs "$CONFIG")
case "${BIN:-}" in */*) BIN=$(abs "$BIN") ;; ?*) BIN=$(command -v "$BIN") ;; esac
cd "$(dirname "$0")/.."
SPLIT=${SPLIT:-0.3}
SELECT=${SELECT:-0.15}
MINUTES=${MINUTES:-10}
EVAL_SECONDS=${EVAL_SECONDS:-120}
DDPG_EVAL_SECONDS=${DDPG_EVAL_SECONDS:-60}
SEED=${SEED:-0}
DEMOS=${DEMOS:-expert}
IL=${IL:-probe}
IL_EPOCHS=${IL_EPOCHS:-10}
DDPG_FLAGS=${DDPG_FLAGS---search-step 0.1 --failure-resets 0.5 --actor-lr 1e-4 --noise ou --sigma-steering 0.3 --sigma-speed 0.05}
if [ -z "$TUB" ] || [ -z "$OUT" ]; then
  echo "usage: scripts/real-replay.sh TUB OUT: TUB is a recording (a tub folder), OUT the folder to write" >&2
  exit 2
fi
if [ ! -f "$TUB/manifest.json" ]; then
  echo "real-replay: $TUB/manifest.json not found: TUB must be a tub (DonkeyCar v2 or jetpilot's)" >&2
  exit 2
fi
if [ -e "$OUT/poses" ]; then
  echo "real-replay: $OUT/poses exists: give a new OUT (nothing is overwritten)" >&2
  exit 2
fi
case "$IL" in probe) IL_FILE=probe.onnx ;; finetune) IL_FILE=last.onnx ;; *)
  echo "real-replay: IL must be probe or finetune, got '$IL'" >&2
  exit 2
  ;;
esac
case "$DEMOS" in expert | none) ;; *)
  echo "real-replay: DEMOS must be expert or none, got '$DEMOS'" >&2
  exit 2
  ;;
esac
EARLY=$(awk -v s="$SPLIT" 'BEGIN { if (!(s > 0 && s < 1)) exit 1; printf "%.4f", 1 - s }') || {
  echo "real-replay: SPLIT must lie between 0 and 1, got '$SPLIT'" >&2
  exit 2
}
LATE=$(awk -v s="$SPLIT" -v m="$SELECT" 'BEGIN { if (!(m >= 0 && m < s)) exit 1; printf "%.4f", 1 - s + m }') || {
  echo "real-replay: SELECT must be 0 or more and below SPLIT ($SPLIT), got '$SELECT'" >&2
  exit 2
}
PARTS=(early middle late)
PICK=middle
SELECT_ARGS=(--select-sim middle.toml)
if [ "$LATE" = "$EARLY" ]; then
  PARTS=(early late)
  PICK=early
  SELECT_ARGS=()
fi
if [ -z "${CONFIG:-}" ]; then
  if grep -q 'wheels/left' "$TUB/manifest.json"; then CONFIG=""; else CONFIG=config/donkeycar.toml; fi
fi
scripts/install-imagenet-weights.sh > /dev/null
. scripts/lib/binary.sh
jetpilot_binary --features train --quiet
mkdir -p "$OUT"
B=$(abs "$B")
CFG=()
[ -n "$CONFIG" ] && CFG=(--config "$(abs "$CONFIG")")

echo "real-replay: poses of $TUB"
"$B" poses --tub "$TUB" ${CFG[@]+"${CFG[@]}"} --out "$OUT/poses" --check-views --turn-from-loops \
  > "$OUT/poses.log" 2>&1

# The replays: replay.toml with the span of each part (the serialiser writes the array
# over several lines).
span() {
  sed "/^recording_span = \[/,/^\]/c\\recording_span = [$1, $2]" "$OUT/poses/replay.toml" > "$OUT/poses/$3"
  grep -qF "recording_span = [$1, $2]" "$OUT/poses/$3" || {
    echo "real-replay: replay.toml changed shape: recording_span not set in $OUT/poses/$3" >&2
    exit 1
  }
}
span 0.0 "$EARLY" early.toml
if [ "$PICK" = middle ]; then span "$EARLY" "$LATE" middle.toml; fi
span "$LATE" 1.0 late.toml

echo "real-replay: imitation on the earliest $EARLY of the frames"
rm -rf "$OUT/il"
if [ "$IL" = probe ]; then
  "$B" -q train probe --data "$OUT/poses" --config "$OUT/poses/replay.toml" --head speed-steering \
    --grid 1 --leave-latest "$SPLIT" -o "$OUT/il" > "$OUT/il.log" 2>&1
else
  "$B" -q train il --data "$OUT/poses" --config "$OUT/poses/replay.toml" --init imagenet \
    --input-size 96 --head speed-steering --epochs "$IL_EPOCHS" --seed "$SEED" \
    --leave-latest "$SPLIT" -o "$OUT/il" > "$OUT/il.log" 2>&1
fi
"$B" -q score --model "$OUT/il/$IL_FILE" --data "$OUT/poses" --config "$OUT/poses/replay.toml" \
  --split-by-time "$SPLIT" --out "$OUT/score" > "$OUT/score.txt"

evaluate() { # NAME MODEL|--expert SUFFIX: eval on every part's replay
  local pilot=(--model "$2")
  [ "$2" = --expert ] && pilot=(--expert)
  for part in "${PARTS[@]}"; do
    (cd "$OUT/poses" && "$B" eval --config "$part$3.toml" "${pilot[@]}" --seconds "$EVAL_SECONDS" \
      --json "$OUT/eval_$1_$part.json" --png "$OUT/eval_$1_$part.png" > "$OUT/eval_$1_$part.txt" 2>&1)
  done
}
# The bar: the scripted expert (pure pursuit, lookahead 0.22 m) at the recording's mean
# speed, in replays that differ from the ones above in [sim.expert] only.
SPEED=$(awk -F, 'NR > 1 { if (n) d += sqrt(($3 - x) ^ 2 + ($4 - y) ^ 2); x = $3; y = $4; t = $2; n++ }
  END { if (t > 0) printf "%.3f", d / t; else print "0.2" }' "$OUT/poses/poses.csv")
for part in "${PARTS[@]}"; do
  sed -e "/^\[sim.expert\]/,/^\[/ s/^speed_mps = .*/speed_mps = $SPEED/" \
    -e "/^\[sim.expert\]/,/^\[/ s/^max_lateral_accel = .*/max_lateral_accel = 100.0/" \
    "$OUT/poses/$part.toml" > "$OUT/poses/${part}_expert.toml"
  grep -qF "speed_mps = $SPEED" "$OUT/poses/${part}_expert.toml" || {
    echo "real-replay: replay.toml changed shape: [sim.expert] speed_mps not set" >&2
    exit 1
  }
done
echo "real-replay: eval of the scripted expert at $SPEED m/s (the bar)"
evaluate expert --expert _expert
echo "real-replay: eval of the imitation policy"
evaluate il "$OUT/il/$IL_FILE" ""
DEMO_ARGS=()
if [ "$DEMOS" = expert ]; then
  echo "real-replay: the expert's recovery demonstrations in the early replay"
  rm -rf "$OUT/demos"
  (cd "$OUT/poses" && "$B" sim --config early_expert.toml --expert --seconds 60 --swerve-every 3 \
    --record-every 3 --record "$OUT/demos" > "$OUT/demos.log" 2>&1)
  DEMO_ARGS=(--demos "$OUT/demos")
fi
echo "real-replay: DDPG against the early replay, $MINUTES minutes, best.onnx picked on the $PICK replay"
rm -rf "$OUT/ddpg"
# shellcheck disable=SC2086 # DDPG_FLAGS is a list of flags
(cd "$OUT/poses" && "$B" train ddpg --sim early.toml ${SELECT_ARGS[@]+"${SELECT_ARGS[@]}"} \
  --init "$OUT/il/$IL_FILE" --out "$OUT/ddpg" ${DEMO_ARGS[@]+"${DEMO_ARGS[@]}"} --minutes "$MINUTES" --eval-seconds "$DDPG_EVAL_SECONDS" --eval-every 10 \
  --seed "$SEED" $DDPG_FLAGS > "$OUT/ddpg.log" 2>&1)
evaluate ddpg_last "$OUT/ddpg/last.onnx" ""
evaluate ddpg_best "$OUT/ddpg/best.onnx" ""

# The report.
field() { # FILE KEY: a number from eval's JSON
  grep -m1 "\"$2\"" "$1" | sed 's/.*: *//; s/,$//'
}
row() { # NAME
  local cells=""
  for part in "${PARTS[@]}"; do
    local j="$OUT/eval_$1_$part.json"
    cells="$cells | $(field "$j" interventions) | $(printf '%.0f' "$(field "$j" autonomy_percent)") % | $(printf '%.1f' "$(field "$j" distance_m)") m"
  done
  echo "| $1$cells |"
}
{
  echo "# Real replay of $(basename "$TUB")"
  echo
  echo "\`scripts/real-replay.sh $TUB $OUT\` (IL=$IL SPLIT=$SPLIT SELECT=$SELECT MINUTES=$MINUTES EVAL_SECONDS=$EVAL_SECONDS DDPG_EVAL_SECONDS=$DDPG_EVAL_SECONDS SEED=$SEED), $(date -u +%Y-%m-%d), $(git rev-parse --short HEAD 2>/dev/null || echo '?')."
  echo
  echo "## Poses (\`poses/poses.png\`, \`poses/check-views.png\`)"
  echo
  echo '```'
  grep -v '^20..-..-..T' "$OUT/poses.log"
  echo '```'
  echo
  echo "## Imitation on the earliest $EARLY, scored on the latest $SPLIT of the frames"
  echo
  echo '```'
  cat "$OUT/score.txt"
  echo '```'
  echo
  if [ "$PICK" = middle ]; then
    echo "## Closed loop: $EVAL_SECONDS s on each replay (shares of the recording in time; early, 0-$EARLY: the training part; middle, $EARLY-$LATE: where best.onnx is picked; late, $LATE-1: held out from everything)"
    echo
    echo "| policy | early: interventions | autonomy | distance | middle: interventions | autonomy | distance | late: interventions | autonomy | distance |"
    echo "|---|---|---|---|---|---|---|---|---|---|"
  else
    echo "## Closed loop: $EVAL_SECONDS s on each replay (early: the training part, where best.onnx is picked; late: held out)"
    echo
    echo "| policy | early: interventions | autonomy | distance | late: interventions | autonomy | distance |"
    echo "|---|---|---|---|---|---|---|"
  fi
  row expert
  row il
  row ddpg_last
  row ddpg_best
  echo
  grep -m1 '^DDPG:' "$OUT/ddpg.log" || echo "DDPG: no summary line in ddpg.log"
  echo
  if [ "$DEMOS" = expert ]; then
    echo "- Demonstrations: $(grep -m1 '^recorded' "$OUT/demos.log" || echo 'none recorded'); the expert's drive that recorded them: $(awk '/^ +interventions/ { print $2 " interventions, autonomy " $4 " %" }' "$OUT/demos.log")."
  else
    echo "- Demonstrations: none (DEMOS=none)."
  fi
  echo "- DDPG flags: ${DDPG_FLAGS:-the defaults}."
  # ddpg_eval.csv: episode,env_steps,wall_s,interventions,...; the first row is the start.
  awk -F, -v e="$DDPG_EVAL_SECONDS" -v w="$PICK" 'NR == 2 { s = $4 } NR > 2 { v[++n] = $4 }
    END {
      if (!n) { print "- DDPG evaluations (" e " s, " w " replay): only the start"; exit }
      for (i = 1; i <= n; i++) for (j = i + 1; j <= n; j++) if (v[j] < v[i]) { t = v[i]; v[i] = v[j]; v[j] = t }
      m = (n % 2) ? v[(n + 1) / 2] : (v[n / 2] + v[n / 2 + 1]) / 2
      printf "- DDPG evaluations (%s s, %s replay): start %d interventions; the %d later ones: median %s, %d to %d\n", e, w, s, n, m, v[1], v[n]
    }' "$OUT/ddpg/ddpg_eval.csv"
  # ddpg_episodes.csv: ...,critic_loss,mean_q (columns 8, 9); the first and the last tenth.
  awk -F, 'NR > 1 && $9 != "NaN" && $9 != "" { q[++n] = $9; l[n] = $8 }
    END {
      if (n < 10) { printf "- Critic: %d episodes with updates, too few for a trend\n", n; exit }
      k = int(n / 10); for (i = 1; i <= k; i++) { a += q[i]; b += q[n - k + i]; c += l[i]; d += l[n - k + i] }
      printf "- Critic: mean Q %.1f over the first tenth of the episodes with updates, %.1f over the last; critic loss %.1f, then %.1f\n", a / k, b / k, c / k, d / k
    }' "$OUT/ddpg/ddpg_episodes.csv"
  echo
  echo "expert: the scripted expert (pure pursuit) at the recording's mean speed, $SPEED m/s: the replay is drivable where it has no interventions."
  echo "Traces: \`eval_<policy>_<part>.png\`; DDPG's curve: \`ddpg/ddpg_curve.png\`."
} > "$OUT/report.md"
echo "real-replay: wrote $OUT/report.md"
