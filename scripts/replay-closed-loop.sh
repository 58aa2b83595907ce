#!/usr/bin/env bash
# Issue 12's whole loop, where the truth is known (docs/guides/training.md, "Replay a real recording"; measured: docs/results/replay-closed-loop.md): a
# continuous drive recorded in the simulator as a robot would record it (JetBot's fisheye,
# a randomised look, wheel-speed noise, recovery swerves recorded too), its poses estimated
# by `jetpilot poses`, the recorded path as the road (`sim.road = "path"`), IL + DDPG
# against that replay, and the policy tested on the rendered track. The same pipeline on
# the drive's true poses is the reference.
#
#   scripts/replay-closed-loop.sh [OUT]        (default OUT: .cache/replay-loop)
#
# 1. The drive: the mat clockwise, DRIVE_S simulated seconds at 30 Hz, one randomised look
#    for the whole drive (one camera in one room), the expert's swerves recorded too (a
#    person who leaves the recorder running).
# 2. The imitation policy (96x96), trained on a second drive in the same world: the owner's
#    demonstrations, recorded as JetBot users are told to (only the way back from each
#    swerve). Not on the replayed drive itself: the replay re-projects exactly the frames
#    it was trained on, where it drives cleanly and DDPG has nothing to fix (measured:
#    0 interventions on the replay, 22 in 600 s on fresh frames). It does not depend on
#    poses, so both pipelines start from it.
# 3. The drive's poses estimated (`poses --check --out`: from the first true pose, the
#    truth's rewards and labels left out), and a replay config on each set of poses.
# 4. The imitation policy on both replays and on the rendered track; then IL + DDPG on
#    each replay (same seed, same wall budget, the same demonstrations with rewards: 331
#    frames of the mat counter-clockwise with recoveries and randomised looks), each
#    tested on the rendered track, clockwise, in the drive's own world: the same seed and
#    randomisation, so the same look as the recording (the room it was recorded in).
#
# Environment: SEED (sim.seed: the drive's look and the world's draws, default 0), MINUTES
# (DDPG wall budget per run, default 15), IL_EPOCHS (default 10:
# about 1000 frames, neighbours alike at 30 Hz), DRIVE_S (default 40: 1.2 laps), EVAL_S
# (the rendered-track tests, default 600), BIN (a built jetpilot with --features train;
# default: build target/release/jetpilot),
# ILDDPG_FLAGS (default: the levers of the paper's experiment, docs/results/paper-experiment.md, with smaller steering noise, no
# failure resets and the pull towards the imitation policy kept: on the path road the
# rendered mat's OU 0.3 left the replay's bounds within seconds, and as the pull decayed
# the actor collapsed), POSES (default "true est": which replays get IL + DDPG), IL_SWERVE
# (the demonstration drive's seconds between swerves, default 4; the replayed drive's are
# 3, so the two drives differ), PATH_LANES (default 2: the drive is the right lane of the
# mat's two-lane road, so drifting into the other lane costs reward, as on the rendered
# mat, instead of ending the episode; 1: the road is the drive's own lane), REPLAY_HEADING
# (default 30: the replay's heading bound, degrees; VISTA's 18 ended the imitation policy's
# replayed drive 3 times as often as the rendered track does, every time by that bound,
# while JetBot's 160-degree lens still covers 78 % of the ground at 30). Steps already
# done (their output is complete) are skipped, so an interrupted run goes on. About 1 h on
# 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-.cache/replay-loop}
MINUTES=${MINUTES:-15}
IL_EPOCHS=${IL_EPOCHS:-10}
DRIVE_S=${DRIVE_S:-40}
EVAL_S=${EVAL_S:-600}
ILDDPG_FLAGS=${ILDDPG_FLAGS:---search-step 0.1 --anchor-decay-updates 0 --failure-resets 0 --actor-lr 1e-4 --noise ou --sigma-steering 0.1 --sigma-speed 0.05}
POSES=${POSES:-true est}
IL_SWERVE=${IL_SWERVE:-4}
SEED=${SEED:-0}
PATH_LANES=${PATH_LANES:-2}
REPLAY_HEADING=${REPLAY_HEADING:-30}
if [ -n "${BIN:-}" ]; then
  B=$BIN
else
  scripts/install-build-deps.sh
  ORT_DYLIB_PATH=${ORT_DYLIB_PATH:-$(scripts/install-onnxruntime.sh)}
  export ORT_DYLIB_PATH
  cargo build --release --features train --locked
  B=target/release/jetpilot
fi
mkdir -p "$OUT"
log() { echo "== $(date +%H:%M:%S) $*"; }

# The world: wheel-speed noise 10 % (as the odometry study). The drive, and the tests in its
# world, keep one look (also after an intervention).
sed "s/^speed_noise = .*/speed_noise = 0.1/; s/^seed = .*/seed = $SEED/" config/sim.toml > "$OUT/sim-noise.toml"
sed 's/^redraw_every_frames = .*/redraw_every_frames = 0/; s/^redraw_at_reset = .*/redraw_at_reset = false/' \
  "$OUT/sim-noise.toml" > "$OUT/drive.toml"

if [ ! -d "$OUT/demos" ]; then
  log demonstrations
  $B -q sim --config "$OUT/sim-noise.toml" --expert --randomise --seconds 60 --swerve-every 3 \
    --record-every 3 --record-frames 331 --record "$OUT/demos" --png "$OUT/demos-png"
fi
if [ ! -d "$OUT/drive" ]; then
  log "the drive (clockwise, swerves recorded)"
  $B -q sim --config "$OUT/drive.toml" --expert --reverse --randomise --seconds "$DRIVE_S" \
    --swerve-every 3 --record-swerves --record "$OUT/drive" --png "$OUT/drive-png"
fi
if [ ! -d "$OUT/il-drive" ]; then
  log "the owner's demonstrations (clockwise, the same world, only the way back recorded)"
  $B -q sim --config "$OUT/drive.toml" --expert --reverse --randomise --seconds "$DRIVE_S" \
    --swerve-every "$IL_SWERVE" --record "$OUT/il-drive" --png "$OUT/il-drive-png"
fi
# Finished when its summary line is in the log (best.onnx appears after the first epoch);
# an interrupted run resumes after its last finished epoch.
if ! grep -q '^imitation learning:' "$OUT/il.log" 2> /dev/null; then
  log "imitation learning on the demonstrations ($IL_EPOCHS epochs)"
  resume=()
  [ -f "$OUT/il/il_state.json" ] && resume=(--resume)
  $B train il --config "$OUT/sim-noise.toml" --input-size 96 --head speed-steering \
    --epochs "$IL_EPOCHS" --data "$OUT/il-drive" --out "$OUT/il" "${resume[@]}" >> "$OUT/il.log" 2>&1
fi
if [ ! -d "$OUT/drive-est" ]; then
  log "poses"
  $B poses --tub "$OUT/drive" --config "$OUT/sim-noise.toml" --check --png "$OUT/odometry.png" \
    --out "$OUT/drive-est" | tee "$OUT/odometry.txt"
fi
IL=$OUT/il/best.onnx
for poses in true est; do
  tub=drive
  [ "$poses" = est ] && tub=drive-est
  sed "s|^frames = .*|frames = \"replay\"|; s|^# recording = .*|recording = \"$tub\"|; s|^road = .*|road = \"path\"|; s|^lanes = .*|lanes = $PATH_LANES|; s|^replay_max_heading_deg = .*|replay_max_heading_deg = $REPLAY_HEADING|" \
    "$OUT/sim-noise.toml" > "$OUT/path-$poses.toml"
done

# The imitation policy before DDPG: on both replays (120 s, as DDPG's own tests there) and
# on the rendered track, clockwise, in the drive's look.
TRACK=(--config "$OUT/drive.toml" --reverse --randomise)
for poses in true est; do
  [ -f "$OUT/eval_il_path_$poses.json" ] || $B -q eval --config "$OUT/path-$poses.toml" --model "$IL" \
    --seconds 120 --json "$OUT/eval_il_path_$poses.json" --png "$OUT/il_path_$poses.png"
done
[ -f "$OUT/eval_il_track.json" ] || $B -q eval "${TRACK[@]}" --model "$IL" \
  --seconds "$EVAL_S" --json "$OUT/eval_il_track.json" --png "$OUT/il_track.png"

# IL + DDPG against each replay, the same seed and wall budget; then the rendered track.
for poses in $POSES; do
  # last.onnx is written when the run ends (best.onnx at its first evaluation); an
  # interrupted run starts again.
  if [ ! -f "$OUT/ddpg_$poses/last.onnx" ]; then
    rm -rf "$OUT/ddpg_$poses"
    log "IL + DDPG on the $poses poses ($MINUTES min)"
    # shellcheck disable=SC2086
    $B train ddpg --sim "$OUT/path-$poses.toml" --seed 1 --init "$IL" --demos "$OUT/demos" \
      --minutes "$MINUTES" $ILDDPG_FLAGS --eval-seconds 120 --eval-every 10 \
      --out "$OUT/ddpg_$poses" > "$OUT/ddpg_$poses.log" 2>&1
  fi
  [ -f "$OUT/eval_ddpg_${poses}_track.json" ] || $B -q eval "${TRACK[@]}" \
    --model "$OUT/ddpg_$poses/best.onnx" --seconds "$EVAL_S" \
    --json "$OUT/eval_ddpg_${poses}_track.json" --png "$OUT/ddpg_${poses}_track.png"
done
log done
for f in "$OUT"/eval_*.json; do
  printf '%-28s' "$(basename "$f" .json)"
  grep -o '"\(interventions\|autonomy_percent\|rewards\)": [-0-9.]*' "$f" | tr '\n' ' '
  echo
done
