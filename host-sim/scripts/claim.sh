#!/usr/bin/env bash
# Issue 14's claim on the 3x3 map (README "The claim, measured"): GMAN (Efficient mode,
# α = 1e-2) against its controls — gman-noemd (θ trained by the outer loop, no inner loop),
# A3C+FG and A3C — over SEEDS at UPDATES each, all 8000 val episodes per run, GMAN also with
# adaptation off at test time; then the table with Welch's t against GMAN. Re-running skips
# what is done (an interrupted training resumes exactly).
#   DATA=../shared/data/gman SEEDS="1 2 3 4 5" bash host-sim/scripts/claim.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p gman-host-sim --bin gman
G=./target/release/gman
D=${DATA:-../shared/data/gman}
R=${OUT:-runs/claim}
U=${UPDATES:-15000}
mkdir -p "$R"/{gman,gman-adaptoff,gman-noemd,a3c-fg,a3c}
[ -f "$R/fg/fg.ckpt" ] || $G pretrain-fg --data "$D" --preset mcu --seed 1 --out "$R/fg" --quiet
run() {
  local method=$1 s=$2; shift 2
  local dir="$R/runs/$method-s$s"
  if [ -f "$dir/checkpoint.ckpt" ]; then
    $G train --data "$D" --resume "$dir" --updates "$U" --quiet
  else
    $G train --data "$D" --preset mcu --fg "$R/fg/fg.ckpt" --map 3x3 --method "$method" \
      --updates "$U" --seed "$s" --out "$dir" --quiet "$@"
  fi
  [ -f "$R/$method/s$s.json" ] || $G eval --data "$D" --split val \
    --agent "$dir/checkpoint.ckpt" --json "$R/$method/s$s.json" --quiet
}
for s in ${SEEDS:-1 2 3 4 5}; do
  run gman "$s" --inner-lr 0.01
  [ -f "$R/gman-adaptoff/s$s.json" ] || $G eval --data "$D" --split val \
    --agent "$R/runs/gman-s$s/checkpoint.ckpt" --method gman-noemd \
    --json "$R/gman-adaptoff/s$s.json" --quiet
  run gman-noemd "$s"
  run a3c-fg "$s"
  run a3c "$s"
done
$G table --runs "$R"/gman "$R"/gman-adaptoff "$R"/gman-noemd "$R"/a3c-fg "$R"/a3c
