#!/usr/bin/env bash
# The float-sensitive tests on more than one SIMD level of this x86-64 CPU.
#
# burn's Flex backend (macerator, gemm) and ONNX Runtime (MLAS) pick their kernels at run
# time from cpuid: AVX-512, AVX2+FMA, or SSE. They have no switch to force a level, so the
# older level comes from qemu-user, whose emulated CPU reports the features of the model
# named (Nehalem: SSE4.2, no AVX). QEMU's TCG cannot emulate AVX-512; on a machine that
# has it, the native run is the AVX-512 one. Tests that spawn the jetpilot binary run it
# natively, so only the in-process float work runs on the emulated CPU.
#
#   scripts/test-simd-levels.sh            # native, then -cpu Nehalem (~12 min under qemu)
#   QEMU_CPUS="Nehalem Haswell" scripts/test-simd-levels.sh
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-build-deps.sh >/dev/null
if ! command -v qemu-x86_64 >/dev/null; then
  apt-get update -qq && apt-get install -y -qq qemu-user >/dev/null
fi
ORT_DYLIB_PATH=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH

native=$(grep -o -m1 -w -E 'avx512f' /proc/cpuinfo || grep -o -m1 -w -E 'avx2' /proc/cpuinfo || echo sse)
# test target, then its name filter: the tests whose floats cross implementations (Flex
# against the float64 reference, Flex against ONNX Runtime). The rest of the suite compares
# runs on one code path; under qemu it would take hours.
suites=(
  "--test integration|train_gradients::a_training_step_on_flex"
  "--test integration|train_parity::"
)
run_level() {
  local label=$1 runner=$2
  for s in "${suites[@]}"; do
    local target=${s%%|*} filter=${s#*|}
    echo "== $label: cargo test $target $filter"
    # shellcheck disable=SC2086
    CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER="$runner" \
      cargo test --all-features --locked $target -- $filter 2>&1 | grep -E '^test result|FAILED|panicked'
    [ "${PIPESTATUS[0]}" -eq 0 ] || { echo "test-simd-levels: FAIL on $label" >&2; exit 1; }
  done
}
run_level "native ($native)" ""
for cpu in ${QEMU_CPUS:-Nehalem}; do
  run_level "qemu-x86_64 -cpu $cpu" "qemu-x86_64 -cpu $cpu"
done
echo "test-simd-levels: ok"
