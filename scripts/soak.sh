#!/usr/bin/env bash
# Soak (issue 51): the daemon for FRAMES frames on looping simulator frames at the camera's
# top rate, with a 96x96 int8 model, virtual motors (`motors.backend = "log"`, every command
# a JSON line in OUT/motors.jsonl), the web page on with one MJPEG client watching and one
# page (scripts/soak-client.py) holding the controls in Auto, so the autopilot drives every
# frame. Every INTERVAL seconds it samples the daemon's RSS, open file descriptors and
# threads, and /metrics (frames, commands, watchdog stops, each stage's mean latency over
# the window) into OUT/soak.csv, then prints the first and last tenth side by side, and the
# gaps between drive commands (median, p99, largest) of the first and last tenth of the run
# (OUT/gaps.csv per tenth).
#
#   scripts/soak.sh FRAMES [OUT]        e.g. scripts/soak.sh 1000000 .cache/soak
#
# FPS (default 240, the camera's top rate), INTERVAL (default 10 s) and PORT (default 8897)
# change the run.
set -euo pipefail
cd "$(dirname "$0")/.."

FRAMES=${1:-}
OUT=${2:-.cache/soak}
FPS=${FPS:-240}
INTERVAL=${INTERVAL:-10}
PORT=${PORT:-8897}
if ! [[ "$FRAMES" =~ ^[0-9]+$ ]] || [ "$FRAMES" -eq 0 ]; then
  echo "usage: scripts/soak.sh FRAMES [OUT]: FRAMES must be a positive number of frames, got '$FRAMES'" >&2
  exit 2
fi
. scripts/lib/binary.sh
jetpilot_binary --quiet
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

# 200 simulator frames (JetBot xy names: the quantizer's calibration reads them too).
if [ ! -f "$OUT/model.onnx" ]; then
  rm -rf "$OUT/frames"
  "$B" -q sim --config config/sim.toml --scatter 200 --record-xy "$OUT/frames" > /dev/null
  "$B" -q model init --input-size 96 --seed 1 -o "$OUT/model_fp32.onnx"
  "$B" -q model quantize "$OUT/model_fp32.onnx" --calibration "$OUT/frames" -o "$OUT/model.onnx"
fi
cat > "$OUT/soak.toml" <<EOF
[camera]
source = "folder"
path = "$OUT/frames"
fps = $FPS
loop = true

[model]
path = "$OUT/model.onnx"

[motors]
backend = "log"
log_path = "$OUT/motors.jsonl"

[log]
stats_interval_s = 60.0
print_commands = false

[web]
enabled = true
bind = "127.0.0.1:$PORT"
EOF

DURATION=$(( (FRAMES + FPS - 1) / FPS ))
echo "soak: $FRAMES frames at $FPS fps: at least $DURATION s; samples every $INTERVAL s into $OUT/soak.csv"
rm -f "$OUT/motors.jsonl"
"$B" run --config "$OUT/soak.toml" --duration "$DURATION" > "$OUT/daemon.log" 2>&1 &
PID=$!
VIDEO=
HOLDER=
cleanup() {
  [ -n "$VIDEO" ] && kill "$VIDEO" 2>/dev/null || true
  [ -n "$HOLDER" ] && kill "$HOLDER" 2>/dev/null || true
  kill "$PID" 2>/dev/null || true
}
trap cleanup EXIT
for _ in $(seq 100); do
  curl -sf "http://127.0.0.1:$PORT/api/status" > /dev/null && break
  sleep 0.2
done
curl -sN "http://127.0.0.1:$PORT/video" > /dev/null &
VIDEO=$!
python3 scripts/soak-client.py hold "$PORT" 2> "$OUT/holder.log" &
HOLDER=$!
for _ in $(seq 50); do
  curl -sf "http://127.0.0.1:$PORT/api/status" | grep -q '"mode":"auto"' && break
  sleep 0.2
done
if ! curl -sf "http://127.0.0.1:$PORT/api/status" | grep -q '"mode":"auto"'; then
  echo "soak: the page holder did not put the daemon in Auto (see $OUT/holder.log)" >&2
  exit 1
fi

metric() { awk -v k="$1" '$1 == k { print $2; exit }' "$OUT/metrics.txt"; }
stage() { # mean latency (ms) of a stage over the window: (sum - sum0) / (count - count0)
  local s c
  s=$(metric "jetpilot_stage_latency_seconds_sum{stage=\"$1\"}")
  c=$(metric "jetpilot_stage_latency_seconds_count{stage=\"$1\"}")
  echo "${s:-0} ${c:-0}"
}
echo "t_s,rss_kb,fds,threads,frames,commands,watchdog_stops,frames_per_s,preprocess_ms,inference_ms" > "$OUT/soak.csv"
t0=$(date +%s)
declare -A last=([frames]=0 [t]=$t0 [ps]=0 [pc]=0 [is]=0 [ic]=0)
while kill -0 "$PID" 2>/dev/null; do
  sleep "$INTERVAL"
  kill -0 "$PID" 2>/dev/null || break
  curl -sf "http://127.0.0.1:$PORT/metrics" > "$OUT/metrics.txt" || continue
  now=$(date +%s)
  rss=$(awk '/^VmRSS:/ { print $2 }' "/proc/$PID/status")
  threads=$(awk '/^Threads:/ { print $2 }' "/proc/$PID/status")
  fds=$(find "/proc/$PID/fd" -mindepth 1 -maxdepth 1 2>/dev/null | wc -l)
  frames=$(metric jetpilot_frames_captured_total)
  commands=$(metric jetpilot_commands_written_total)
  stops=$(metric jetpilot_watchdog_stops_total)
  read -r ps pc <<< "$(stage preprocess)"
  read -r is ic <<< "$(stage inference)"
  awk -v t="$((now - t0))" -v rss="$rss" -v fds="$fds" -v th="$threads" -v f="$frames" \
    -v c="$commands" -v w="$stops" -v f0="${last[frames]}" -v dt="$((now - ${last[t]}))" \
    -v ps="$ps" -v pc="$pc" -v ps0="${last[ps]}" -v pc0="${last[pc]}" \
    -v is="$is" -v ic="$ic" -v is0="${last[is]}" -v ic0="${last[ic]}" 'BEGIN {
      fps = dt > 0 ? (f - f0) / dt : 0
      pm = pc > pc0 ? 1000 * (ps - ps0) / (pc - pc0) : 0
      im = ic > ic0 ? 1000 * (is - is0) / (ic - ic0) : 0
      printf "%d,%d,%d,%d,%d,%d,%d,%.1f,%.3f,%.3f\n", t, rss, fds, th, f, c, w, fps, pm, im
    }' >> "$OUT/soak.csv"
  last=([frames]=$frames [t]=$now [ps]=$ps [pc]=$pc [is]=$is [ic]=$ic)
done
wait "$PID" || echo "soak: the daemon exited with status $? (see $OUT/daemon.log)" >&2

# The first and the last tenth of the samples (the first sample is warm-up).
awk -F, 'NR > 1 { n++; row[n] = $0 } END {
  if (n < 3) { print "soak: fewer than 3 samples; run longer"; exit }
  k = int(n / 10); if (k < 1) k = 1
  for (part = 0; part < 2; part++) {
    a = part ? n - k + 1 : 2; b = part ? n : 1 + k
    rss = fds = th = fps = im = 0; m = 0
    for (i = a; i <= b; i++) { split(row[i], v, ","); rss += v[2]; fds += v[3]; th += v[4]; fps += v[8]; im += v[10]; m++ }
    printf "%s tenth (%d samples): RSS %.1f MiB, %.0f fds, %.0f threads, %.0f frames/s, inference %.2f ms\n",
      part ? "last " : "first", m, rss / m / 1024, fds / m, th / m, fps / m, im / m
  }
  split(row[n], v, ",")
  printf "frames %d, commands %d, watchdog stops %d\n", v[5], v[6], v[7]
}' "$OUT/soak.csv" | tee "$OUT/summary.txt"
python3 scripts/soak-client.py gaps "$OUT/motors.jsonl" "$OUT/gaps.csv" | tee -a "$OUT/summary.txt"

# The figures, with `jetpilot train plot` (a build with the trainer: PLOT_BIN, else the
# debug build the test suite makes).
PLOT=${PLOT_BIN:-target/debug/jetpilot}
if [ -x "$PLOT" ] && "$PLOT" train plot --help > /dev/null 2>&1; then
  "$PLOT" -q train plot --csv "$OUT/soak.csv" --x t_s --y rss_kb -o "$OUT/soak-rss.png" \
    --title "soak: daemon RSS (kB) against time (s)"
  "$PLOT" -q train plot --csv "$OUT/gaps.csv" --x tenth --y p99_ms -o "$OUT/soak-gaps.png" \
    --title "soak: p99 gap between drive commands (ms), per tenth of the run"
  echo "soak: figures $OUT/soak-rss.png, $OUT/soak-gaps.png"
else
  echo "soak: no figures: they need a build with the trainer (cargo build --features train; PLOT_BIN=...)" >&2
fi
