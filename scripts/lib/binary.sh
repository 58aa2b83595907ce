# Sourced (not run) by the study scripts, from the repository root: the ONNX Runtime
# library and the jetpilot binary they run, got the same way in each.
#
#   . scripts/lib/binary.sh
#   jetpilot_binary --features train      # then "$B" is the binary to run
#
# jetpilot_binary [CARGO_BUILD_ARGS...] exports ORT_DYLIB_PATH (the pinned wheel's library,
# installed once by scripts/install-onnxruntime.sh) and sets B to $BIN when the caller gave
# one; otherwise it installs the build's Debian packages (scripts/install-build-deps.sh,
# idempotent), builds with `cargo build --release --locked CARGO_BUILD_ARGS` and sets B to
# target/release/jetpilot. A BIN must then already hold the features the script needs.
jetpilot_binary() {
  ORT_DYLIB_PATH=$(scripts/install-onnxruntime.sh)
  export ORT_DYLIB_PATH
  if [ -n "${BIN:-}" ]; then
    B=$BIN
  else
    scripts/install-build-deps.sh
    cargo build --release --locked "$@"
    B=target/release/jetpilot
  fi
}
