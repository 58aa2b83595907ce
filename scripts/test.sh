#!/usr/bin/env bash
# The whole test suite, on a fresh machine: installs what it needs (the ONNX Runtime library
# from the pinned wheel), then runs every unit, hardware-in-the-loop and integration test
# with all features, and prints the total. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-build-deps.sh
ORT_LIB=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH="$ORT_LIB"
LOG=$(mktemp)
trap 'rm -f "$LOG"' EXIT
set +e
cargo test --all-features --all-targets --locked "$@" 2>&1 | tee "$LOG"
status=${PIPESTATUS[0]}
set -e
passed=$(grep -Eo '^test result: .* ([0-9]+) passed' "$LOG" | grep -Eo '[0-9]+ passed' | awk '{s+=$1} END {print s+0}')
failed=$(grep -Eo '[0-9]+ failed' "$LOG" | awk '{s+=$1} END {print s+0}')
echo
echo "total: $passed passed, $failed failed"
exit "$status"
