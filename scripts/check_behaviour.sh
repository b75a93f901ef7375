#!/usr/bin/env bash
# Behaviour check: short training runs and evaluations whose outputs must not change under a
# refactoring.
#
#   scripts/check_behaviour.sh GMAN OUT_DIR [DATA_DIR]
#
# GMAN is the `gman` binary to run (e.g. target/release/gman), DATA_DIR the GMAN benchmark
# data (default ../shared/data/gman). The first call records into OUT_DIR; a later call with
# the same OUT_DIR records into OUT_DIR.new and compares every recorded file with `cmp`,
# exiting non-zero on the first difference listed (all are listed).
#
# What is recorded: the final checkpoint of each training run (a3c and gman at B = 1 and 16,
# on the synthetic world and on the real data with the 3x3 map, plus the inner-loop variants
# below), its metrics.csv without the wall-clock column, and `gman eval --json` of two
# shipped blobs and of a trained checkpoint on a subset of val episodes.
set -euo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 GMAN OUT_DIR [DATA_DIR]" >&2
  exit 2
fi
GMAN=$(realpath "$1")
OUT=$2
DATA=${3:-../shared/data/gman}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
MODELS="$ROOT/host-sim/models"
[ -x "$GMAN" ] || { echo "$GMAN: not an executable" >&2; exit 2; }
[ -f "$DATA/attributes.json" ] || { echo "$DATA: no attributes.json (give DATA_DIR)" >&2; exit 2; }
DATA=$(realpath "$DATA")

if [ -f "$OUT/MANIFEST" ]; then
  REF=$OUT
  DST=$OUT.new
  rm -rf "$DST"
else
  REF=
  DST=$OUT
fi
mkdir -p "$DST"
DST=$(realpath "$DST")
RUNS="$DST/runs"
rm -rf "$RUNS"
mkdir -p "$RUNS"
: >"$DST/MANIFEST"

log() { printf '%s\n' "$*" >&2; }

# keep NAME FILE: copies FILE into the record as NAME.
keep() {
  cp "$2" "$DST/$1"
  echo "$1" >>"$DST/MANIFEST"
}

# keep_csv NAME CSV: metrics.csv without its last column (elapsed seconds).
keep_csv() {
  sed -E 's/,[^,]*$//' "$2" >"$DST/$1"
  echo "$1" >>"$DST/MANIFEST"
}

# train NAME ARGS...: a short training run; its checkpoint and curve are recorded.
train() {
  local name=$1
  shift
  log "train $name: $*"
  "$GMAN" train --config tiny --quiet --out "$RUNS/$name" "$@" >"$RUNS/$name.log" 2>&1 ||
    { cat "$RUNS/$name.log" >&2; exit 1; }
  keep "$name.ckpt" "$RUNS/$name/checkpoint.ckpt"
  keep_csv "$name.metrics.csv" "$RUNS/$name/metrics.csv"
}

# The pre-trained generators, once per world (their checkpoints are recorded too).
REAL=(--data "$DATA" --map 3x3)
pretrain() {
  local w=$1
  shift
  log "pretrain-fg $w"
  "$GMAN" pretrain-fg "$@" --iters 60 --seed 1 --out "$RUNS/fg-$w" --quiet \
    >"$RUNS/fg-$w.log" 2>&1 || { cat "$RUNS/fg-$w.log" >&2; exit 1; }
  keep "fg-$w.ckpt" "$RUNS/fg-$w/fg.ckpt"
}
pretrain syn
pretrain real --data "$DATA"

U=(--updates 3 --workers 2 --min-steps 40)
for m in a3c gman; do
  for b in 1 16; do
    train "$m-b$b-syn" --method $m --batch-envs $b "${U[@]}" --fg "$RUNS/fg-syn/fg.ckpt"
    train "$m-b$b-real" --method $m --batch-envs $b "${U[@]}" --fg "$RUNS/fg-real/fg.ckpt" \
      "${REAL[@]}"
  done
done
FG=(--fg "$RUNS/fg-syn/fg.ckpt")
# The inner loop's other paths: every parameter adapted (Full), the exact meta-gradient,
# a delayed commit, G trained without an inner loop, the imitation objective.
train gman-full-b1-syn --method gman --adapt-mode full --batch-envs 1 "${U[@]}" "${FG[@]}"
train gman-full-b16-syn --method gman --adapt-mode full --batch-envs 16 "${U[@]}" "${FG[@]}"
train gman-meta2-syn --method gman --adapt-mode full --meta-order 2 --batch-envs 1 \
  --updates 2 --workers 1 --min-steps 30 "${FG[@]}"
train gman-delay3-b1-syn --method gman --commit-delay 3 --batch-envs 1 "${U[@]}" "${FG[@]}"
train gman-delay3-b4-syn --method gman --commit-delay 3 --batch-envs 4 "${U[@]}" "${FG[@]}"
train gman-noemd-b4-syn --method gman-noemd --batch-envs 4 "${U[@]}" "${FG[@]}"
train a3c-fg-dagger-b1-syn --method a3c-fg --objective dagger --batch-envs 1 "${U[@]}" "${FG[@]}"
train a3c-fg-dagger-b4-syn --method a3c-fg --objective dagger --batch-envs 4 "${U[@]}" "${FG[@]}"

# A resumed run: 2 updates, then on to 3.
log "train a3c-b16-resume-syn"
"$GMAN" train --config tiny --quiet --out "$RUNS/a3c-b16-resume-syn" --method a3c --batch-envs 16 \
  --updates 2 --workers 2 --min-steps 40 >"$RUNS/resume.log" 2>&1 || { cat "$RUNS/resume.log" >&2; exit 1; }
"$GMAN" train --quiet --resume "$RUNS/a3c-b16-resume-syn" --updates 3 >>"$RUNS/resume.log" 2>&1 ||
  { cat "$RUNS/resume.log" >&2; exit 1; }
keep a3c-b16-resume-syn.ckpt "$RUNS/a3c-b16-resume-syn/checkpoint.ckpt"

# Evaluations: two shipped blobs on the real data, a trained checkpoint on the synthetic world.
# The report names the agent's path: each runs from the run folder with a relative one.
mkdir -p "$RUNS/blobs"
cp "$MODELS/gman-map3-b16-mcu-int8-seed1.gman" "$MODELS/a3c-map3-b16-mcu-int8-seed1.gman" "$RUNS/blobs/"
ev() {
  local name=$1
  shift
  log "eval $name: $*"
  (cd "$RUNS" && "$GMAN" eval --quiet --json "$name.json" "$@") >"$RUNS/$name.eval.log" 2>&1 ||
    { cat "$RUNS/$name.eval.log" >&2; exit 1; }
  keep "$name.json" "$RUNS/$name.json"
}
ev eval-gman-blob --data "$DATA" --agent blobs/gman-map3-b16-mcu-int8-seed1.gman --episodes 8
ev eval-a3c-blob --data "$DATA" --agent blobs/a3c-map3-b16-mcu-int8-seed1.gman --episodes 8
ev eval-gman-ckpt-syn --agent gman-b16-syn/checkpoint.ckpt --episodes 20

if [ -z "$REF" ]; then
  log "recorded $(wc -l <"$DST/MANIFEST") files into $DST"
  exit 0
fi
bad=0
while read -r f; do
  if ! cmp -s "$REF/$f" "$DST/$f"; then
    echo "DIFFERS: $f" >&2
    bad=1
  fi
done <"$REF/MANIFEST"
if ! cmp -s "$REF/MANIFEST" "$DST/MANIFEST"; then
  echo "DIFFERS: the list of recorded files" >&2
  bad=1
fi
if [ $bad = 0 ]; then
  log "same: all $(wc -l <"$REF/MANIFEST") files of $REF equal those of $DST"
fi
exit $bad
