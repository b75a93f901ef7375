#!/usr/bin/env bash
# 1 process x 2 workers against 2 MPI ranks x 1 worker, for a3c and gman (mcu, B = 16), in
# one run: env steps/s of each and what the ranks' exchange costs per update.
#   bash host-sim/scripts/mpi-bench.sh            (UPDATES=20 by default)
# Needs OpenMPI (`apt-get install libopenmpi-dev openmpi-bin libclang-dev`).
set -euo pipefail
cd "$(dirname "$0")/../.."
G=${GMAN:-./target/release/gman}
[ -n "${GMAN:-}" ] || cargo build --release -p gman-host-sim --features mpi --bin gman
U=${UPDATES:-20}
R=$(mktemp -d)
trap 'rm -rf "$R"' EXIT
$G pretrain-fg --iters 20 --quiet --out "$R/fg" 2>/dev/null
common=(--preset mcu --batch-envs 16 --updates "$U" --fg "$R/fg/fg.ckpt" --quiet)
for m in a3c gman; do
  echo "== $m: 1 process x 2 workers"
  $G train --method "$m" "${common[@]}" --workers 2 --out "$R/$m-1x2" 2>&1 | grep '^trained'
  echo "== $m: 2 ranks x 1 worker"
  mpirun -n 2 --oversubscribe --allow-run-as-root ${BIND:---bind-to none} \
    $G train --method "$m" "${common[@]}" --workers 1 --out "$R/$m-2x1" 2>&1 | grep -E '^(trained|mpi:)'
  cmp "$R/$m-1x2/checkpoint.ckpt" "$R/$m-2x1/checkpoint.ckpt" && echo "checkpoints identical"
done
