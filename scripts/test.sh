#!/usr/bin/env bash
# The whole test suite, on a fresh machine: installs what it needs (the ONNX Runtime library
# from the pinned wheel), then runs every unit, hardware-in-the-loop and integration test
# with all features. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
ORT_LIB=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH="$ORT_LIB"
cargo test --all-features --locked "$@"
