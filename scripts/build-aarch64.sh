#!/usr/bin/env bash
# Cross-builds jetpilot for a Jetson Nano on JetPack 4.6 (aarch64, Ubuntu 18.04, glibc 2.27)
# without Docker, checks the binary's glibc floor and runs the library's unit tests under
# qemu-user. Installs what it needs, idempotently:
#   - rustup target aarch64-unknown-linux-gnu
#   - Debian packages: qemu-user, binutils-aarch64-linux-gnu, libc6-dev-arm64-cross,
#     linux-libc-dev-arm64-cross (aarch64 C and kernel headers for bindgen; the loader and
#     libc qemu runs the tests with), libclang-dev (scripts/install-build-deps.sh)
#   - zig from PyPI (`ziglang`) in a venv under .cache/zig-venv, and cargo-zigbuild
#
#   scripts/build-aarch64.sh              # build + glibc check + unit tests under qemu
#   SKIP_TESTS=1 scripts/build-aarch64.sh # build + glibc check only
#
# Output: target/aarch64-unknown-linux-gnu/release/jetpilot (under $CARGO_TARGET_DIR if set)
#
# `cargo zigbuild --target aarch64-unknown-linux-gnu.2.27` links against zig's glibc 2.27
# stubs, so the binary cannot pick up a symbol version newer than JetPack 4.6 has; the
# objdump check below proves it. Cross.toml + cross/Dockerfile are the Docker route.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS

TARGET=aarch64-unknown-linux-gnu
GLIBC_FLOOR=2.27
ZIG_VERSION=0.15.2
VENV=.cache/zig-venv
ZIGBUILD_VERSION=0.24.1
# Lib unit tests that cannot run under qemu-user, skipped by exact name, each with its
# reason. Empty: every lib unit test runs there (qemu-user 7.2: 221 passed, the 2 tests
# marked #[ignore] in the source are skipped on every platform).
QEMU_SKIP=()

log() { echo "== build-aarch64: $*" >&2; }

# --- Debian packages --------------------------------------------------------------------
scripts/install-build-deps.sh
need=()
for p in qemu-user binutils-aarch64-linux-gnu libc6-dev-arm64-cross linux-libc-dev-arm64-cross; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then need+=(python3-venv); fi
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO=sudo
  log "installing ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

# --- Rust target, zig, cargo-zigbuild ------------------------------------------------------
if ! rustup target list --installed | grep -qx "$TARGET"; then
  log "rustup target add $TARGET"
  rustup target add "$TARGET"
fi
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -m ziglang version 2>/dev/null | grep -qx "$ZIG_VERSION"; then
  log "zig $ZIG_VERSION from PyPI into $VENV"
  mkdir -p .cache
  python3 -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "ziglang==$ZIG_VERSION"
fi
# cargo-zigbuild runs `python3 -m ziglang` when no `zig` is on PATH: the venv's python3.
export PATH="$PWD/$VENV/bin:$PATH"
if ! cargo zigbuild --help >/dev/null 2>&1; then
  log "cargo install cargo-zigbuild --version $ZIGBUILD_VERSION --locked"
  cargo install cargo-zigbuild --version "$ZIGBUILD_VERSION" --locked --quiet
fi

# bindgen (v4l2-sys-mit) must parse the aarch64 kernel/libc headers, not the host's:
# Debian's arm64 cross headers. The variable is the hyphenated name bindgen looks up first;
# cargo-zigbuild appends zig's include dirs to it, but zig 0.15 reports its lib dir relative
# to the working directory when it lies under it (.cache/zig-venv here), so clang ignores
# those ("nonexistent directory") and these are what it uses.
BINDGEN_ENV="BINDGEN_EXTRA_CLANG_ARGS_$TARGET=-I/usr/aarch64-linux-gnu/include"

# --- release build ---------------------------------------------------------------------
log "cargo zigbuild --release --target $TARGET.$GLIBC_FLOOR"
t0=$SECONDS
env "$BINDGEN_ENV" cargo zigbuild --release --locked --target "$TARGET.$GLIBC_FLOOR"
build_s=$((SECONDS - t0))
BIN=${CARGO_TARGET_DIR:-target}/$TARGET/release/jetpilot
file "$BIN" 2>/dev/null || true

# --- glibc floor -----------------------------------------------------------------------
versions=$(aarch64-linux-gnu-objdump -T "$BIN" | grep -o 'GLIBC_[0-9][0-9.]*' | sed 's/GLIBC_//' | sort -uV)
highest=$(printf '%s\n' "$versions" | tail -n 1)
if [ -z "$highest" ]; then
  echo "build-aarch64: no GLIBC symbol versions found in $BIN (not dynamically linked?)" >&2
  exit 1
fi
echo "highest GLIBC symbol version needed by $BIN: $highest (floor $GLIBC_FLOOR)"
newer=()
for v in $versions; do
  [ "$(printf '%s\n%s\n' "$v" "$GLIBC_FLOOR" | sort -V | tail -n 1)" = "$GLIBC_FLOOR" ] || newer+=("$v")
done
if [ ${#newer[@]} -gt 0 ]; then
  echo "build-aarch64: FAIL: $BIN needs glibc ${newer[*]} > $GLIBC_FLOOR (JetPack 4.6); symbols:" >&2
  for v in "${newer[@]}"; do aarch64-linux-gnu-objdump -T "$BIN" | grep -F "GLIBC_$v " >&2 || true; done
  exit 1
fi

# The binary starts (dynamic loader, glibc, relocations) under qemu with an arm64 libc.
if ! qemu-aarch64 -L /usr/aarch64-linux-gnu "$BIN" --version; then
  echo "build-aarch64: FAIL: $BIN does not start under qemu-aarch64" >&2
  exit 1
fi

# --- unit tests under qemu ---------------------------------------------------------------
if [ "${SKIP_TESTS:-0}" = 1 ]; then
  echo "build-aarch64: tests skipped (SKIP_TESTS=1); build ${build_s}s, total $((SECONDS - start))s"
  exit 0
fi
# Release profile: the dependencies are the ones the build above compiled already.
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64 -L /usr/aarch64-linux-gnu"
skip=()
for t in "${QEMU_SKIP[@]}"; do skip+=(--skip "$t"); done
[ ${#skip[@]} -eq 0 ] || skip+=(--exact)
log "cargo-zigbuild test --release --lib --target $TARGET.$GLIBC_FLOOR (runner: qemu-aarch64)"
t0=$SECONDS
# The tests' own build of jetpilot at opt-level 1 (the dependencies stay the release build's
# above, so nothing else is rebuilt): its compile took 5 minutes of CI at opt-level 3, and
# no test depends on the optimiser (Rust does not contract or reorder floating point).
env "$BINDGEN_ENV" cargo-zigbuild test --release --locked --lib --target "$TARGET.$GLIBC_FLOOR" \
  --config 'profile.release.package.jetpilot.opt-level=1' -- "${skip[@]}"
test_s=$((SECONDS - t0))
echo "build-aarch64: ok: build ${build_s}s, tests ${test_s}s, total $((SECONDS - start))s"
