#!/usr/bin/env bash
# The zero-step control of the domain-shift study (docs/domain-shift.md, "The zero-step
# control"): every kept int8 blob of a row with an inner loop (results/shift/models/S-ROW-sN.gman,
# ROW in ROWS, default gman gman-ref), evaluated on all 8000 val episodes at its own S twice:
# with adaptation on, and with the inner loop running at a zero rate (--inner-lr 0 sets α2 = 0;
# α1 is then 0 too, gman's α1 being α2 and gman-ref's its own 0), so the same updates run and
# draw the same random numbers, and no parameter moves (tests/tests/navigator.rs). Kept as
# results/shift/S/ROW-int8/sN.json and results/shift/S/ROW-int8-step0/sN.json; what exists is
# skipped, so the script resumes and picks up new blobs. KEEP=results/paper runs the same
# control on the reference-budget sweep's blobs (models/ROW-sN.gman, at S = 1), kept as
# results/paper/ROW-int8/sN.json and results/paper/ROW-int8-step0/sN.json.
#
#   DATA=../shared/data/gman nice -n 10 bash host-sim/scripts/shift-step0.sh
#
# GMAN=path/to/gman picks the binary (default: target/release/gman, built if missing).
set -euo pipefail
cd "${REPO:-$(dirname "$0")/../..}"
D=${DATA:-../shared/data/gman}
K=${KEEP:-results/shift}
ROWS=${ROWS:-gman gman-ref}
G=${GMAN:-target/release/gman}
[ -x "$G" ] || cargo build --release -p gman-host-sim --bin gman
for row in $ROWS; do
  for m in "$K"/models/*"$row"-s*.gman; do
    [ -f "$m" ] || continue
    b=$(basename "$m" .gman)
    s=${b##*"$row"-s}
    case $b in
      "$row"-s*) S=1 dir=$K/$row ;;  # a sweep at the default simulator: models/ROW-sN.gman
      *-"$row"-s*) S=${b%%-"$row"-s*} dir=$K/$S/$row ;;
      *) continue ;;
    esac
    # (S and N must be numbers: a name like models/x-gman-s1.gman belongs to another row)
    case $S$s in *[!0-9.]*) continue ;; esac
    for v in int8 int8-step0; do
      out=$dir-$v/s$s.json
      [ -f "$out" ] && continue
      mkdir -p "$(dirname "$out")"
      extra=()
      [ "$v" = int8-step0 ] && extra=(--inner-lr 0)
      "$G" eval --data "$D" --object-layout thor5 --domain-shift "$S" --split val \
        --agent "$m" "${extra[@]}" --json "$out.$$.tmp" --quiet
      mv "$out.$$.tmp" "$out"  # (per-process name: two workers may meet on one file)
      echo "[$(date +%H:%M:%S)] $out"
    done
  done
done
