#!/usr/bin/env bash
# The odometry study of `jetpilot poses` (docs/guides/collecting-data.md, "Poses for a recording without them"; measured: docs/results/odometry.md):
# simulated laps recorded with JetBot's fisheye camera, their known poses taken as the
# truth, and the drift of the estimate (vision + wheels) and of the wheels alone, at
# 30/15/10 Hz, with noise and blur, and with a wheel model 10 % off.
#
#   scripts/odometry-study.sh OUT_DIR [SECONDS]
#
# Needs the release build (cargo build --release). About 10 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: scripts/odometry-study.sh OUT_DIR [SECONDS]}
SECONDS_SIM=${2:-33}
B=target/release/jetpilot
mkdir -p "$OUT"
# Wheel-speed noise on (10 % per physics step), the rest as config/sim.toml.
sed 's/^speed_noise = .*/speed_noise = 0.1/' config/sim.toml > "$OUT/sim-noise.toml"
# The estimator's wheel model 10 % off (wheel base 13 cm, top speed 0.45 m/s): a real
# robot's motor model is only ever roughly known.
sed 's/^wheel_base_m = .*/wheel_base_m = 0.13/; s/^top_speed_mps = .*/top_speed_mps = 0.45/' \
  "$OUT/sim-noise.toml" > "$OUT/sim-off.toml"
record() { # NAME EXTRA_ARGS...
  local name=$1; shift
  [ -d "$OUT/$name" ] || $B -q sim --config "$OUT/sim-noise.toml" --expert --seconds "$SECONDS_SIM" \
    --record "$OUT/$name" "$@" > /dev/null
}
record lap
record lap-randomised --randomise
check() { # LABEL TUB CONFIG EXTRA_ARGS...
  local label=$1 tub=$2 cfg=$3; shift 3
  echo "== $label"
  $B poses --tub "$OUT/$tub" --config "$OUT/$cfg" --check --png "$OUT/${label// /_}.png" "$@" | grep -v '^trace'
}
check "30 Hz" lap sim-noise.toml
check "15 Hz" lap sim-noise.toml --every 2
check "10 Hz" lap sim-noise.toml --every 3
check "30 Hz noise 8" lap sim-noise.toml --noise 8
check "30 Hz blur 2" lap sim-noise.toml --blur 2
check "30 Hz randomised looks" lap-randomised sim-noise.toml
check "30 Hz wheel model off" lap sim-off.toml
check "10 Hz wheel model off" lap sim-off.toml --every 3
check "30 Hz randomised, wheel model off" lap-randomised sim-off.toml
