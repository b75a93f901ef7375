#!/usr/bin/env bash
# The claim on the 3x3 map (docs/results-earlier.md): GMAN (Efficient mode,
# α = 1e-2) against its controls — gman-noemd (θ trained by the outer loop, no inner loop),
# A3C+FG and A3C — over SEEDS at UPDATES each, all 8000 val episodes per run, GMAN also with
# adaptation off at test time; then the table with Welch's t against GMAN. Re-running skips
# what is done (an interrupted training resumes exactly). EXTRA=1 adds the other methods of
# the results table (gman-cossim, and a3c-ps / gman-ps with a pre-trained PS module) for the
# seeds in EXTRA_SEEDS.
#   DATA=../shared/data/gman SEEDS="1 2 3 4 5" bash host-sim/scripts/claim.sh
# The defaults are B = 16 and 6000 updates; the one-episode-at-a-time runs are
#   BATCH_ENVS=1 UPDATES=15000 OUT=runs/claim bash host-sim/scripts/claim.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p gman-host-sim --bin gman
G=./target/release/gman
D=${DATA:-../shared/data/gman}
# The documented numbers were measured with the seeded object placement (LAYOUT=thor5 or
# auto: the AI2-THOR 5.0 positions, see docs/data.md).
LAYOUT=${LAYOUT:-rule}
R=${OUT:-runs/claim-b16}
U=${UPDATES:-6000}
B=${BATCH_ENVS:-16}
mkdir -p "$R"/{gman,gman-adaptoff,gman-noemd,a3c-fg,a3c,gman-cossim,gman-cossim-adaptoff,a3c-ps,gman-ps}
[ -f "$R/fg/fg.ckpt" ] || $G pretrain-fg --data "$D" --object-layout "$LAYOUT" --preset mcu --seed 1 --out "$R/fg" --quiet
run() {
  local method=$1 s=$2; shift 2
  local dir="$R/runs/$method-s$s"
  if [ -f "$dir/checkpoint.ckpt" ]; then
    $G train --data "$D" --object-layout "$LAYOUT" --resume "$dir" --updates "$U" --quiet
  else
    $G train --data "$D" --object-layout "$LAYOUT" --preset mcu --fg "$R/fg/fg.ckpt" --batch-envs "$B" --map 3x3 --method "$method" \
      --updates "$U" --seed "$s" --out "$dir" --quiet "$@"
  fi
  [ -f "$R/$method/s$s.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val \
    --agent "$dir/checkpoint.ckpt" --json "$R/$method/s$s.json" --quiet
}
for s in ${SEEDS:-1 2 3 4 5}; do
  run gman "$s" --inner-lr 0.01
  [ -f "$R/gman-adaptoff/s$s.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val \
    --agent "$R/runs/gman-s$s/checkpoint.ckpt" --method gman-noemd \
    --json "$R/gman-adaptoff/s$s.json" --quiet
  run gman-noemd "$s"
  run a3c-fg "$s"
  run a3c "$s"
done
if [ "${EXTRA:-0}" = 1 ]; then
  [ -f "$R/ps/ps.ckpt" ] || $G pretrain-ps --data "$D" --object-layout "$LAYOUT" --seed 1 --out "$R/ps" --quiet
  for s in ${EXTRA_SEEDS:-1 2 3}; do
    run gman-cossim "$s" --inner-lr 0.01
    [ -f "$R/gman-cossim-adaptoff/s$s.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val \
      --agent "$R/runs/gman-cossim-s$s/checkpoint.ckpt" --method gman-noemd \
      --json "$R/gman-cossim-adaptoff/s$s.json" --quiet
    run a3c-ps "$s" --ps "$R/ps/ps.ckpt"
    run gman-ps "$s" --inner-lr 0.01 --ps "$R/ps/ps.ckpt"
  done
fi
$G table --runs "$R"/gman "$R"/gman-adaptoff "$R"/gman-noemd "$R"/a3c-fg "$R"/a3c
[ "${EXTRA:-0}" = 1 ] && $G table --runs "$R"/gman-cossim "$R"/gman-cossim-adaptoff "$R"/a3c-ps "$R"/gman-ps
exit 0
