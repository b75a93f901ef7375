#!/usr/bin/env bash
# Keeps the small outputs of the reference-budget sweep (host-sim/scripts/paper-tables.sh) in a
# folder that can be committed, and lays them back into a sweep directory on another machine,
# so that a restarted sweep skips every finished run.
#
#   bash host-sim/scripts/paper-keep.sh save    OUT KEEP   # OUT -> KEEP (finished runs only)
#   bash host-sim/scripts/paper-keep.sh restore KEEP OUT   # KEEP -> OUT (never overwrites)
#
# What is kept of a finished run ROW-sS (one whose ROW/sS.json exists): every evaluation JSON
# of the sweep (ROW/sS.json, ROW-adaptoff/sS.json, gman-nometa/sS.json, random/sS.json), the
# learning curve (runs/ROW-sS/curve/kN.json and kN.at) and the training curve: metrics.csv
# reduced to the columns `gman plot` reads (update, episodes, env_steps, success_rate,
# mean_reward), gzip-compressed, and the run's int8 blob (models/ROW-sS.gman, 345 KB); the
# sweep's PS module (ps/ps.ckpt, 1.1 MB), with which the PS rows' blobs are evaluated.
# Checkpoints are not kept (5 MB each).
set -euo pipefail
[ $# -eq 3 ] || { sed -n '2,13p' "$0" >&2; exit 2; }
mode=$1 src=$2 dst=$3
[ -d "$src" ] || { echo "$src: no such directory" >&2; exit 2; }
mkdir -p "$dst"

# copy SRC DST: copies a file unless DST exists (restore) or is the same (save).
copy() {
  mkdir -p "$(dirname "$2")"
  if [ "$mode" = restore ] && [ -e "$2" ]; then return 0; fi
  cmp -s "$1" "$2" 2>/dev/null || cp "$1" "$2"
}

case $mode in
  save)
    # the PS module, which the PS rows' blobs need (`gman eval --ps`)
    [ -f "$src/ps/ps.ckpt" ] && copy "$src/ps/ps.ckpt" "$dst/ps/ps.ckpt"
    for json in "$src"/*/s[0-9]*.json; do
      [ -e "$json" ] || continue
      rel=${json#"$src"/}
      copy "$json" "$dst/$rel"
    done
    for run in "$src"/runs/*-s[0-9]*; do
      [ -d "$run" ] || continue
      name=$(basename "$run") row=${name%-s*} s=${name##*-s}
      [ -f "$src/$row/s$s.json" ] || continue # still training
      for f in "$run"/curve/k*.json "$run"/curve/k*.at; do
        [ -e "$f" ] && copy "$f" "$dst/runs/$name/curve/$(basename "$f")"
      done
      # KEEP_MODELS=PREFIX keeps the blob as PREFIX$name.gman (the domain-shift study's
      # results/shift/models/S-ROW-sN.gman) instead of KEEP/models/$name.gman
      [ -f "$src/models/$name.gman" ] && copy "$src/models/$name.gman" "${KEEP_MODELS:-$dst/models/}$name.gman"
      out=$dst/runs/$name/metrics.csv.gz
      if [ ! -f "$out" ] || [ "$run/metrics.csv" -nt "$out" ]; then
        cut -d, -f1-5 "$run/metrics.csv" | gzip -9n >"$out"
      fi
    done
    ;;
  restore)
    (cd "$src" && find . -type f) | while read -r rel; do
      rel=${rel#./}
      case $rel in
        *metrics.csv.gz)
          csv=$dst/${rel%.gz}
          [ -e "$csv" ] || { mkdir -p "$(dirname "$csv")" && gunzip -c "$src/$rel" >"$csv"; } ;;
        README.md) ;;
        *) copy "$src/$rel" "$dst/$rel" ;;
      esac
    done
    ;;
  *) echo "unknown mode $mode (save or restore)" >&2; exit 2 ;;
esac
