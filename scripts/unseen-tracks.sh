#!/usr/bin/env bash
# Tracks a policy never saw (issue 11, deliver 5d; docs/results/sim-to-real.md): the
# paper's 600 s test on the default mat and on the other shipped tracks, both directions,
# through JetBot's fisheye with plain looks. Each track as built (the JetBot mat:
# counter-clockwise) and reversed (`eval --reverse`).
#
#   scripts/unseen-tracks.sh MODEL [OUT]   (e.g. .cache/s2r/randomised/il/best.onnx)
#
# SECONDS_PER_TEST=600 (default) sets the test length; CAMERA=jetbot (default) or pinhole
# the camera (CAMERA= for the config's). Writes OUT/<track>[_rev].{json,png} and prints one
# table row per test. BIN=target/release/jetpilot skips the build. ONLY (a grep -E pattern on
# <track>[_rev], e.g. 'narrow.*_rev') runs some tests only.
set -euo pipefail
cd "$(dirname "$0")/.."

MODEL=${1:-}
OUT=${2:-.cache/unseen-tracks}
TEST_S=${SECONDS_PER_TEST:-600}
CAMERA=${CAMERA-jetbot}
if [ -z "$MODEL" ] || [ ! -f "$MODEL" ]; then
  echo "usage: scripts/unseen-tracks.sh MODEL [OUT]: MODEL must be an ONNX policy file" >&2
  echo "(e.g. .cache/s2r/randomised/il/best.onnx from scripts/sim-to-real.sh); '${MODEL}' is not one" >&2
  exit 2
fi

. scripts/lib/binary.sh
jetpilot_binary
CAM=()
if [ -n "$CAMERA" ]; then
  CAM=(--camera "$CAMERA")
fi
mkdir -p "$OUT"

echo "| track | direction | interventions | autonomy | laps | rewards |"
echo "|---|---|---|---|---|---|"
for track in config/tracks/*.toml; do
  name=$(basename "$track" .toml)
  for dir in fwd rev; do
    rev=()
    tag=$name
    if [ "$dir" = rev ]; then
      rev=(--reverse)
      tag=${name}_rev
    fi
    grep -qE "${ONLY:-.}" <<< "$tag" || continue
    "$B" -q eval --config config/sim.toml --model "$MODEL" --track "$track" "${rev[@]}" \
      "${CAM[@]}" --seconds "$TEST_S" --json "$OUT/$tag.json" --png "$OUT/$tag.png" > "$OUT/$tag.txt"
    python3 - "$OUT/$tag.json" "$name" "$dir" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
d = "reversed" if sys.argv[3] == "rev" else "as built"
print(f"| {sys.argv[2]} | {d} | {r['interventions']} | {r['autonomy_percent']:.1f} % "
      f"| {r['laps']:.1f} | {r['rewards']} of {r['control_steps']} |")
EOF
  done
done
