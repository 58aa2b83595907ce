#!/usr/bin/env bash
# Faults while busy (issue 51): the fault matrix again with both cores and the disk loaded,
# and the worst time from a fault to the motors stopped, held to the watchdog period.
#
#   scripts/faults-under-load.sh [ROUNDS] [OUT]      e.g. scripts/faults-under-load.sh 50
#
# Load: stress-ng (installed with apt where missing; plain shell loops and dd where it
# cannot be) with 2 CPU workers, 1 I/O-sync worker and 1 disk writer, for the whole run.
# Under it:
# - the daemon as a process (tests/integration/process_faults.rs), ROUNDS rounds of each at
#   random moments: SIGTERM; SIGKILL then `jetpilot stop` (the unit's ExecStopPost); the
#   camera's command killed mid-run. The motors' log is polled every millisecond;
# - the in-process fault tests (tests/integration/daemon.rs: a stalled, failing and
#   unplugged camera, NaN and out-of-range outputs, an ONNX Runtime error, a panicking
#   model, one I2C error and a burst of them), and the full-disk recording tests, ROUNDS
#   times over (at most 10).
# Each test asserts its own outcome (motors stopped, the right error, the tub readable);
# each round's stop time goes to OUT/times.csv (kind,round,delay_ms,stop_ms,drove,
# last_drive_ms: the process rounds also time the last drive command from the fault), and
# the summary (OUT/summary.txt) gives the worst per kind. Exit status 1 when a test
# failed or a stop took longer than the watchdog period (250 ms, the shipped default; the
# in-process tests run with 200 ms). A stalled camera is stopped by the watchdog itself,
# so its time (`stalled_camera_past_watchdog`) counts from the end of the period.
set -euo pipefail
cd "$(dirname "$0")/.."

ROUNDS=${1:-50}
OUT=${2:-.cache/faults-under-load}
WATCHDOG_MS=250
if ! [[ "$ROUNDS" =~ ^[0-9]+$ ]] || [ "$ROUNDS" -eq 0 ]; then
  echo "usage: scripts/faults-under-load.sh [ROUNDS] [OUT]: ROUNDS must be a positive number, got '$ROUNDS'" >&2
  exit 2
fi
scripts/install-build-deps.sh
ORT_DYLIB_PATH=$(scripts/install-onnxruntime.sh)
export ORT_DYLIB_PATH
if ! command -v stress-ng > /dev/null && [ "$(id -u)" -eq 0 ]; then
  echo "faults-under-load: apt-get install stress-ng" >&2
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq stress-ng > /dev/null 2>&1 ||
    { apt-get update -qq > /dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq stress-ng > /dev/null 2>&1; } ||
    echo "faults-under-load: stress-ng not installed; loading with shell loops and dd" >&2
fi
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
rm -f "$OUT/times.csv" "$OUT"/in-process-*.log

# Build before loading the machine: the tests, and the release binary that the process
# rounds run (the robot's build; the 250 MB debug binary starts far slower under disk load).
cargo nextest run --all-features --test integration --lib --no-run --locked
cargo build --release --locked
export JETPILOT_BIN="$PWD/target/release/jetpilot"

LOAD_DIR=$(mktemp -d)
LOAD=()
stop_load() {
  for p in "${LOAD[@]}"; do kill "$p" 2> /dev/null || true; done
  wait 2> /dev/null || true
  rm -rf "$LOAD_DIR"
}
trap stop_load EXIT
if command -v stress-ng > /dev/null; then
  stress-ng --cpu 2 --io 1 --hdd 1 --hdd-bytes 256M --temp-path "$LOAD_DIR" --timeout 0 \
    > "$OUT/stress-ng.log" 2>&1 &
  LOAD+=($!)
  LOAD_DESC="stress-ng --cpu 2 --io 1 --hdd 1 --hdd-bytes 256M"
else
  for _ in 1 2; do
    (while :; do :; done) &
    LOAD+=($!)
  done
  (while :; do dd if=/dev/zero of="$LOAD_DIR/load" bs=1M count=256 conv=fsync status=none; done) &
  LOAD+=($!)
  LOAD_DESC="2 shell busy loops and a dd writer (256 MiB, fsync)"
fi
sleep 2
echo "faults-under-load: $ROUNDS rounds under $LOAD_DESC; times in $OUT/times.csv"

status=0
export JETPILOT_FAULT_TIMES="$OUT/times.csv"
# As under systemd: no RUST_BACKTRACE (symbolizing a panic's backtrace in a debug build
# takes ~170 ms before the dying stage's channel closes; the watchdog bounds it anyway).
export RUST_BACKTRACE=0
JETPILOT_FAULT_ROUNDS=$ROUNDS cargo nextest run --all-features --test integration --locked \
  --no-fail-fast --test-threads 1 -E 'test(/^process_faults::/)' 2>&1 | tail -n 5 || status=1
IN_PROCESS='test(/^daemon::.*(stops_the_motors|i2c_error)/) | test(/full_disk/)'
REPEAT=$(( ROUNDS < 10 ? ROUNDS : 10 ))
for i in $(seq "$REPEAT"); do
  if ! cargo nextest run --all-features --test integration --lib --locked --no-fail-fast \
    -E "$IN_PROCESS" > "$OUT/in-process-$i.log" 2>&1; then
    echo "faults-under-load: a fault test failed (pass $i of $REPEAT): $OUT/in-process-$i.log" >&2
    grep -E '^ *FAIL' "$OUT/in-process-$i.log" >&2 || true
    status=1
  fi
  grep -E '^ *Summary' "$OUT/in-process-$i.log" || true
done
stop_load
trap - EXIT

awk -F, -v wd="$WATCHDOG_MS" -v desc="$LOAD_DESC" '
  { n[$1]++
    if ($5 == "true") { d[$1]++; v = $4 + 0; if (v > w[$1]) w[$1] = v; s[$1] += v; if (v > worst) { worst = v; wk = $1 } }
    if ($6 != "") { l = $6 + 0; if (!($1 in ld) || l > ld[$1]) ld[$1] = l } }
  END {
    printf "under %s\n", desc
    printf "%-30s %6s %6s %9s %9s %16s\n", "fault", "rounds", "drove", "mean ms", "worst ms", "last drive ms"
    for (k in n) printf "%-30s %6d %6d %9.1f %9.1f %16s\n", k, n[k], d[k], d[k] ? s[k] / d[k] : 0, w[k], (k in ld) ? sprintf("%.1f", ld[k]) : "-"
    print "(times from the fault; last drive: the latest drive command after the fault, worst round)"
    printf "worst stop: %.1f ms (%s); watchdog period %d ms\n", worst, wk, wd
    if (worst > wd) { print "FAIL: a stop took longer than the watchdog period"; exit 1 }
  }' "$OUT/times.csv" | tee "$OUT/summary.txt" || status=1
exit "$status"
