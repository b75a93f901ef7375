#!/usr/bin/env bash
# The domain-shift study (docs/results.md, "When does adaptation pay"): every row trained and
# evaluated at each domain shift S (`--domain-shift`, host-sim/SIMULATOR.md): the rows a3c,
# a3c-fg, gman, its control gman-noemd and gman-ref (the reference implementation as released,
# host-sim/scripts/paper-tables.sh) over SEEDS, the privileged-feature bound over
# PRIVILEGED_SEEDS and the random agent over SEEDS, at STEPS environment steps per run
# (default 2 M: the reference-budget sweep's val curves are flat from 2 M on,
# docs/results.md), all 8000 val episodes, with adaptation on and off for the rows with an
# inner loop.
#
#   DATA=../shared/data/gman OUT=runs/shift KEEP=results/shift nice -n 19 bash host-sim/scripts/shift-study.sh
#
# Each level is a sweep directory OUT/S of host-sim/scripts/paper-tables.sh (its run, resume
# and evaluation rules; re-running skips what is done and resumes an interrupted run exactly).
# The loop runs seed by seed over every level, so a partial study is a complete picture over
# fewer seeds. KEEP=DIR keeps every finished run's evaluations as DIR/S/ROW/sN.json
# (adaptation off: DIR/S/ROW-adaptoff/sN.json) and its int8 blob as DIR/models/S-ROW-sN.gman,
# and lays them back into OUT when the study restarts on another machine. The scripts and the
# binary are copied into OUT once, so editing or rebuilding the tree changes no run in flight.
set -euo pipefail
cd "${REPO:-$(dirname "$0")/../..}"
repo=$(pwd)
LEVELS=${LEVELS:-2 1 0 0.5 0.25 0.75}
SEEDS=${SEEDS:-1 2 3}
PRIVILEGED_SEEDS=${PRIVILEGED_SEEDS:-1}
ROWS=${ROWS:-a3c a3c-fg gman gman-noemd gman-ref}
O=${OUT:-runs/shift}
KEEP=${KEEP:-}
mkdir -p "$O/bin" "$O/scripts"
if [ ! -x "$O/bin/gman" ]; then
  cargo build --release -p gman-host-sim --bin gman
  cp target/release/gman "$O/bin/gman"
fi
for f in paper-tables.sh paper-keep.sh; do
  [ -f "$O/scripts/$f" ] || cp "host-sim/scripts/$f" "$O/scripts/$f"
done
[ -z "$KEEP" ] || case $KEEP in /*) ;; *) KEEP=$repo/$KEEP ;; esac
for s in $SEEDS; do
  for S in $LEVELS; do
    mkdir -p "$O/$S/bin"
    [ -x "$O/$S/bin/gman" ] || cp "$O/bin/gman" "$O/$S/bin/gman"
    only=$ROWS
    case " $PRIVILEGED_SEEDS " in *" $s "*) only="$only privileged" ;; esac
    echo "[$(date +%H:%M:%S)] domain shift $S, seed $s: $only"
    # (computed first: a prefix assignment sees the ones before it on its line)
    keep_level=${KEEP:+$KEEP/$S}
    keep_models=${KEEP:+$KEEP/models/$S-}
    REPO=$repo KEEPER=$O/scripts/paper-keep.sh SHIFT=$S STEPS=${STEPS:-2000000} SEEDS=$s \
      EXTRA_SEEDS=$s ONLY="$only" OUT=$O/$S KEEP=$keep_level KEEP_MODELS=$keep_models \
      bash "$O/scripts/paper-tables.sh"
  done
done
