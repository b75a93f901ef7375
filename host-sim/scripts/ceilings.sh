#!/usr/bin/env bash
# Ceiling diagnostics on the real floor plans and the official val episodes (docs/ceilings.md):
# A3C+FG with the pooled observation and with a 3x3 spatial map, each trained
# (a) with the A3C loss, (b) with 30-step training episodes, (c) by DAgger imitation of the
# shortest-path oracle, (d) with the target's true feature in place of G's output; GMAN in the
# device's mode with adaptation on and off; then the recognition probe. Runs land in runs/ceilings/ (existing outputs are reused).
#   DATA=../shared/data/gman SEEDS="1 2" bash host-sim/scripts/ceilings.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release -p gman-host-sim --bin gman --example recognition_probe
G=./target/release/gman
D=${DATA:-../shared/data/gman}
# The documented numbers were measured with the seeded object placement (LAYOUT=thor5 or
# auto: the AI2-THOR 5.0 positions, see docs/data.md).
LAYOUT=${LAYOUT:-rule}
R=${OUT:-runs/ceilings}
U=${UPDATES:-15000}
mkdir -p "$R"
[ -f "$R/fg/fg.ckpt" ] || $G pretrain-fg --data "$D" --object-layout "$LAYOUT" --preset mcu --seed 1 --out "$R/fg" --quiet
[ -f "$R/eval-random.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val --agent random --json "$R/eval-random.json" --quiet
run() {
  local name=$1; shift
  [ -f "$R/$name/checkpoint.ckpt" ] || $G train --data "$D" --object-layout "$LAYOUT" --preset mcu --fg "$R/fg/fg.ckpt" --batch-envs 1 \
    --updates "$U" --out "$R/$name" --quiet "$@"
  [ -f "$R/eval-$name.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val --agent "$R/$name/checkpoint.ckpt" \
    --json "$R/eval-$name.json" --quiet
}
for s in ${SEEDS:-1}; do
  run old-a3cfg-s$s --method a3c-fg --seed "$s"
  run old-a3cfg-cap30-s$s --method a3c-fg --max-steps 30 --seed "$s"
  run old-dagger-s$s --method a3c-fg --objective dagger --seed "$s"
  run old-priv-s$s --method a3c-fg --privileged-feature --seed "$s"
  run map3-a3cfg-s$s --method a3c-fg --map 3x3 --seed "$s"
  run map3-dagger-s$s --method a3c-fg --map 3x3 --objective dagger --seed "$s"
  run map3-priv-s$s --method a3c-fg --map 3x3 --privileged-feature --seed "$s"
  run map3-dagger-priv-s$s --method a3c-fg --map 3x3 --privileged-feature --objective dagger --seed "$s"
  # GMAN meta-trained in the device's (Efficient) mode, then evaluated with adaptation off.
  run map3-gman-a1e-2-s$s --method gman --map 3x3 --inner-lr 0.01 --seed "$s"
  [ -f "$R/adaptoff-map3-gman-a1e-2-s$s.json" ] || $G eval --data "$D" --object-layout "$LAYOUT" --split val \
    --agent "$R/map3-gman-a1e-2-s$s/checkpoint.ckpt" --method gman-noemd \
    --json "$R/adaptoff-map3-gman-a1e-2-s$s.json" --quiet
done
./target/release/examples/recognition_probe "$D" "$R/fg/fg.ckpt" none 20
./target/release/examples/recognition_probe "$D" "$R/fg/fg.ckpt" 3x3 20
$G table --runs "$R"/eval-*.json
