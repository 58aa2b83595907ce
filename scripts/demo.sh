#!/usr/bin/env bash
# The main job on a machine without a robot: the daemon on the bundled sample frames with
# virtual motors, printing each motor command and the stage latencies. Installs the ONNX
# Runtime library and builds what it needs, idempotently.
#
#   scripts/demo.sh              # 10 s
#   scripts/demo.sh --duration 30
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-build-deps.sh
scripts/install-onnxruntime.sh >/dev/null
cargo build --release --locked --quiet
BIN=target/release/jetpilot
MODEL=.cache/demo-model.onnx
if [ ! -f "$MODEL" ]; then
  mkdir -p .cache
  "$BIN" model init --arch resnet18 --input-size 224 --seed 1 -o "$MODEL"
fi
if [ $# -eq 0 ]; then set -- --duration 10; fi
exec "$BIN" run --config config/demo.toml "$@"
