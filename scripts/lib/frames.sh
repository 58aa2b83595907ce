# Sourced (not run) by the real-frame study scripts (real-finetune.sh, probe-curve.sh,
# lp-ft.sh): the frames in capture-time order, the split `jetpilot score --split-by-time 0.2`
# makes of them, folders of links to a part of them, and the numbers of `score`'s text.
#
#   . scripts/lib/frames.sh
#   frames_by_time "$REAL" "$OUT/by_time.txt"
#   TRAIN=$(earlier "$(wc -l < "$OUT/by_time.txt")")
#   link_spread 25 "$TRAIN" "$OUT/by_time.txt" "$OUT/frames_25"

# frames_by_time REALDATA LIST: writes to LIST the non-empty JetBot frames of REALDATA
# (xy_XXX_YYY_<uuid1>.jpg), one path a line, sorted by the uuid1 capture time in their names
# (<time_low>-<time_mid>-<version+time_hi>-...: sorted on time_hi, time_mid, time_low).
frames_by_time() {
  find "$1" -name 'xy_*.jpg' -size +0 | awk -F/ '{
    n = $NF; split(n, p, "_"); split(p[4], u, "-");
    print substr(u[3], 2) u[2] u[1] "\t" $0 }' | sort | cut -f2 > "$2"
}

# earlier N: how many of N frames `score --split-by-time 0.2` keeps for training. It scores
# the latest round(N / 5) (2N is even, so there is no tie to break).
earlier() { echo $(($1 - ($1 * 2 + 5) / 10)); }

# link_first N LIST DIR: a fresh folder DIR of links to the first N frames of LIST.
link_first() {
  rm -rf "$3"
  mkdir -p "$3"
  head -n "$1" "$2" | while read -r f; do ln -s "$f" "$3/"; done
}

# link_spread N TRAIN LIST DIR: a fresh folder DIR of links to N frames spread evenly over
# the first TRAIN of LIST (every (TRAIN / N)-th, from the first).
link_spread() {
  rm -rf "$4"
  mkdir -p "$4"
  awk -v n="$1" -v t="$2" 'NR <= t && (NR - 1) % (t / n) < 1 && c < n { print; c++ }' "$3" \
    | while read -r f; do ln -s "$f" "$4/"; done
}

# mean WHICH SCORE_TXT: the mean error of the "model" or "baseline" line of `score`'s text.
mean() { awk -v w="$1" '$1 == w && $2 == "mean" { print $3 }' "$2"; }
