#!/usr/bin/env bash
# The whole test suite, on a fresh machine: installs what it needs (the Debian packages, the
# ONNX Runtime library from the pinned wheel, cargo-nextest where it is missing), then runs
# every unit, hardware-in-the-loop and integration test with all features, and prints the
# total. Idempotent. Arguments go to `cargo nextest run` (a filter, `-E 'test(/^poses::/)'`,
# `--no-run`, ...).
#
# The runner is cargo-nextest (config in .config/nextest.toml): each test in its own
# process, the tests of all test binaries (the library's, the binary's and the one
# integration binary, tests/integration/) sharing the two cores, where `cargo test` runs
# the binaries one after another and the tests of one binary in threads of one process.
# Measured on this 2-core VM with the tests built, when there were 23 binaries: 424 s
# against 458 s. It also kills a hung test after 10 minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
NEXTEST_VERSION=0.9.143
scripts/install-build-deps.sh
ORT_LIB=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH="$ORT_LIB"
if ! cargo nextest --version >/dev/null 2>&1; then
  echo "test.sh: cargo install cargo-nextest --version $NEXTEST_VERSION --locked" >&2
  cargo install cargo-nextest --version "$NEXTEST_VERSION" --locked --quiet
fi
LOG=$(mktemp)
trap 'rm -f "$LOG"' EXIT
set +e
cargo nextest run --all-features --all-targets --locked "$@" 2>&1 | tee "$LOG"
status=${PIPESTATUS[0]}
set -e
# nextest's last line: "Summary [ 423.554s] 543 tests run: 543 passed, 2 skipped"
summary=$(grep -E '^ *Summary \[' "$LOG" | tail -n 1 || true)
passed=$(grep -Eo '[0-9]+ passed' <<<"$summary" | grep -Eo '[0-9]+' || echo 0)
# A test killed by the slow-timeout is listed as "N timed out", not "failed": both count.
failed=$(awk '{ for (i = 2; i <= NF; i++) if ($i ~ /^failed/ || ($i == "timed" && $(i + 1) ~ /^out/)) s += $(i - 1) }
  END { print s + 0 }' <<<"$summary")
echo
echo "total: $passed passed, $failed failed"
exit "$status"
