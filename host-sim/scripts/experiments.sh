#!/usr/bin/env bash
# Reproduces the README's "Results so far": pre-training, then every method x seed trained on
# the real training scenes and evaluated on all official val episodes.
#   DATA=../shared/data/gman UPDATES=2000 bash host-sim/scripts/experiments.sh
# Results land in runs/real/ (not tracked); `gman table --runs runs/real/eval/*` prints the
# table. Existing outputs are reused, so an interrupted run can be restarted.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p gman-host-sim --bin gman
G=./target/release/gman
D=${DATA:-../shared/data/gman}
# The documented numbers were measured with the seeded object placement (LAYOUT=thor5 or
# auto: the AI2-THOR 5.0 positions, see docs/data.md).
LAYOUT=${LAYOUT:-rule}
R=${OUT:-runs/real}
U=${UPDATES:-2000}
METHODS=${METHODS:-"a3c a3c-fg gman a3c-ps gman-ps gman-cossim"}
mkdir -p "$R/eval"
[ -f "$R/fg/fg.ckpt" ] || $G pretrain-fg --data "$D" --object-layout "$LAYOUT" --preset mcu --seed 1 --out "$R/fg" --quiet
[ -f "$R/ps/ps.ckpt" ] || $G pretrain-ps --data "$D" --object-layout "$LAYOUT" --seed 1 --out "$R/ps" --quiet
[ -f "$R/eval/random.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val --agent random --json "$R/eval/random.json" --quiet
for seed in 1 2 3; do
  for m in $METHODS; do
    out=$R/$m-seed$seed
    [ -f "$out/checkpoint.ckpt" ] || $G train --data "$D" --object-layout "$LAYOUT" --method "$m" --preset mcu --batch-envs 1 --updates "$U" --seed "$seed" \
      --fg "$R/fg/fg.ckpt" --ps "$R/ps/ps.ckpt" --out "$out" --quiet
    mkdir -p "$R/eval/$m"
    [ -f "$R/eval/$m/seed$seed.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val --agent "$out/checkpoint.ckpt" \
      --json "$R/eval/$m/seed$seed.json" --quiet
  done
done
# EMD without meta-learning: the A3C+FG runs with the inner loop switched on at test time.
mkdir -p "$R/eval/gman-nometa"
for seed in 1 2 3; do
  [ -f "$R/eval/gman-nometa/seed$seed.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val --agent "$R/a3c-fg-seed$seed/checkpoint.ckpt" \
    --method gman-nometa --json "$R/eval/gman-nometa/seed$seed.json" --quiet
done
$G table --runs "$R/eval/random.json" $(for m in $METHODS; do echo "$R/eval/$m"; done) "$R/eval/gman-nometa"
