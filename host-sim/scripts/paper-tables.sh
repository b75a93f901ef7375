#!/usr/bin/env bash
# The paper's Tables 2 and 3 at the reference implementation's training budget (8.77 M
# environment steps per run), on the AI2-THOR 5.0 object positions: a3c, a3c-fg, gman and its
# no-inner-loop control gman-noemd over SEEDS (default 5); gman-cossim and the dagger rows
# (a3c-ps, a3c-fg-ps, gman-ps and its control gman-noemd-ps) over EXTRA_SEEDS (default 3); the
# rows gman-zero, gman-noemd-zero and a3c-fg-zero are gman, gman-noemd and a3c-fg with G's noise
# z = 0 (`--noise zero`) over SEEDS.
# Every run is evaluated on all 8000 val episodes after every CHUNK environment steps
# (the learning curve, RUN/curve/*.json) and at the end; a run with an inner loop also with
# adaptation off, and every a3c-fg run also as gman-nometa (the EMD at test time only); the
# privileged-feature ceiling at the same budget; the learning curves, seeds averaged, in
# $OUT/curves.png, and every seed's SR in $OUT/seeds-main.png and $OUT/seeds-other.png.
#
#   DATA=../shared/data/gman OUT=runs/paper nice -n 19 bash host-sim/scripts/paper-tables.sh
#
# (bash reads a script while it runs it: to keep editing the tree, run a copy, e.g.
# `cp host-sim/scripts/paper-tables.sh runs/ && REPO=$PWD bash runs/paper-tables.sh`.)
#
# About 12-20 min per run on 2 idle cores (B = 16, 3x3 map, mcu preset). The runs use a copy
# of the binary ($OUT/bin/gman, made once), so rebuilding the tree does not change runs in
# flight. Re-running the script skips what is done and resumes an interrupted run exactly
# (from its last checkpoint; a run trains to each chunk's step target in one or more resumed
# launches, and resuming changes no bit). The table: `gman table --runs $OUT/gman ...` (below).
#
# ONLY="ROW ..." restricts the sweep to those rows (e.g. ONLY="gman-ps gman-noemd-ps" SEEDS=1 to
# run one comparison before the rest); the tables and curves at the end cover what exists.
#
# KEEP=DIR (e.g. KEEP=results/paper, the folder the repository keeps) lays the finished runs kept
# there into $OUT before the sweep starts, and keeps every run's small outputs there when it
# finishes (host-sim/scripts/paper-keep.sh), so a sweep moved to another machine resumes.
set -euo pipefail
cd "${REPO:-$(dirname "$0")/../..}"
D=${DATA:-../shared/data/gman}
LAYOUT=${LAYOUT:-thor5}
SEEDS=${SEEDS:-1 2 3 4 5}
EXTRA_SEEDS=${EXTRA_SEEDS:-1 2 3}
# the world of every command: the data, the object layout and the domain shift (SHIFT, default 1,
# host-sim/SIMULATOR.md "Domain shift")
W=(--data "$D" --object-layout "$LAYOUT" --domain-shift "${SHIFT:-1}")
R=${OUT:-runs/paper}
STEPS=${STEPS:-8770000}
CHUNK=${CHUNK:-1000000}
B=${BATCH_ENVS:-16}
mkdir -p "$R/bin"
if [ ! -x "$R/bin/gman" ]; then
  cargo build --release -p gman-host-sim --bin gman
  cp target/release/gman "$R/bin/gman"
fi
G=$R/bin/gman
KEEP=${KEEP:-}
KEEPER=${KEEPER:-$(pwd)/host-sim/scripts/paper-keep.sh}
[ -z "$KEEP" ] || [ ! -d "$KEEP" ] || bash "$KEEPER" restore "$KEEP" "$R"
log() { echo "[$(date +%H:%M:%S)] $*"; }
[ -f "$R/fg/fg.ckpt" ] || $G pretrain-fg "${W[@]}" --preset mcu --seed 1 --out "$R/fg" --quiet
# the PS module, when a PS row is selected
ps_rows=" gman-ps gman-noemd-ps a3c-ps a3c-fg-ps "
needs_ps=1
if [ -n "${ONLY:-}" ]; then
  needs_ps=0
  for r in $ONLY; do case $ps_rows in *" $r "*) needs_ps=1 ;; esac; done
fi
[ "$needs_ps" = 0 ] || [ -f "$R/ps/ps.ckpt" ] || $G pretrain-ps "${W[@]}" --seed 1 --out "$R/ps" --quiet
# the random agent, once per seed (random/sN.json with `--seed N-1`: s1 is the default seed 0)
mkdir -p "$R/random"
for s in $SEEDS; do
  [ -f "$R/random/s$s.json" ] || $G eval "${W[@]}" --split val --agent random \
    --seed $((s - 1)) --json "$R/random/s$s.json" --quiet
done

# The last row of a run's metrics.csv: "update env_steps".
last() { tail -n 1 "$1/metrics.csv" | awk -F, '{print $1, $3}'; }

# Trains run directory $1 until its environment steps reach $2: each launch resumes to 90% of
# the update count that the mean steps per update of the last 500 updates says reaches $2
# (episodes grow longer as the policy learns, so the full estimate would overshoot).
advance() {
  local dir=$1 target=$2 u s rate n
  read -r u s < <(last "$dir")
  while [ "$s" -lt "$target" ]; do
    rate=$(tail -n 500 "$dir/metrics.csv" | awk -F, 'NR==1{u0=$1;s0=$3} {u=$1;s=$3} END{r=(u>u0)?(s-s0)/(u-u0):s/u; print (r>0)?r:1}')
    n=$(awk -v r="$rate" -v rem=$((target - s)) 'BEGIN{n=int(0.9*rem/r)+1; print (n<1)?1:n}')
    # Early on the episodes lengthen fast and the rate of the first updates undershoots:
    # at most 1000 updates per launch until 1000 are done (a curve point past its target
    # is measured where the run is, which the `.at` file records).
    [ "$u" -ge 1000 ] || [ "$n" -le 1000 ] || n=1000
    $G train "${W[@]}" --resume "$dir" --updates $((u + n)) --quiet
    read -r u s < <(last "$dir")
  done
}

# run ROW METHOD SEED [train flags...]: trains RUNS/ROW-sSEED, evaluates it every chunk and at
# the end into ROW/sSEED.json.
run() {
  local row=$1 method=$2 s=$3; shift 3
  local dir=$R/runs/$row-s$s k target u st
  [ -f "$R/$row/s$s.json" ] && return 0
  [ -z "${ONLY:-}" ] || case " $ONLY " in *" $row "*) ;; *) return 0 ;; esac
  mkdir -p "$R/$row" "$dir/curve"
  if [ ! -f "$dir/checkpoint.ckpt" ]; then
    log "start $row seed $s"
    $G train "${W[@]}" --preset mcu --fg "$R/fg/fg.ckpt" --batch-envs "$B" \
      --map 3x3 --method "$method" --updates 100 --seed "$s" --out "$dir" --quiet "$@"
  fi
  for ((k = CHUNK; ; k += CHUNK)); do
    target=$((k < STEPS ? k : STEPS))
    [ -f "$dir/curve/k$target.json" ] || {
      advance "$dir" "$target"
      read -r u st < <(last "$dir")
      $G eval "${W[@]}" --split val --agent "$dir/checkpoint.ckpt" \
        --json "$dir/curve/k$target.tmp" --quiet
      # the update and step count the point was measured at, beside the evaluation
      echo "$u,$st" >"$dir/curve/k$target.at"
      mv "$dir/curve/k$target.tmp" "$dir/curve/k$target.json"
      log "$row seed $s: update $u, $st steps"
    }
    [ "$target" -ge "$STEPS" ] && break
  done
  case $row in
    gman | gman-cossim | gman-ps | gman-zero | gman-ref)
      local off=gman-noemd
      [ "$method" = gman-ps ] && off=gman-noemd-ps
      mkdir -p "$R/$row-adaptoff"
      $G eval "${W[@]}" --split val --agent "$dir/checkpoint.ckpt" \
        --method "$off" --json "$R/$row-adaptoff/s$s.json" --quiet ;;
    a3c-fg)
      mkdir -p "$R/gman-nometa"
      $G eval "${W[@]}" --split val --agent "$dir/checkpoint.ckpt" \
        --method gman-nometa --inner-lr 0.01 --json "$R/gman-nometa/s$s.json" --quiet ;;
  esac
  # the int8 blob of the run (gman eval runs it through gman-core; a PS row's blob needs the
  # PS input from outside, `gman export` says so); a privileged-feature model reads the
  # simulator's true target feature, which no device has: it has no blob
  mkdir -p "$R/models"
  [ "$row" = privileged ] || [ -f "$R/models/$row-s$s.gman" ] ||
    $G export --ckpt "$dir/checkpoint.ckpt" --preset mcu --quant int8 --out "$R/models/$row-s$s.gman" >/dev/null
  cp "$dir/curve/k$STEPS.json" "$R/$row/s$s.json"
  [ -z "$KEEP" ] || bash "$KEEPER" save "$R" "$KEEP"
}

# Seed by seed, so that a partial sweep is a complete table over fewer seeds: every row for
# the first EXTRA_SEEDS, then the four main rows for the remaining SEEDS.
main_rows() {
  run gman gman "$1" --inner-lr 0.01
  run gman-noemd gman-noemd "$1"
  run a3c-fg a3c-fg "$1"
  run a3c a3c "$1"
  # the same rows with G's noise z = 0 at navigation (the reference's choice; G's output is
  # then constant between inner updates, which the device caches)
  run gman-zero gman "$1" --inner-lr 0.01 --noise zero
  run gman-noemd-zero gman-noemd "$1" --noise zero
  run a3c-fg-zero a3c-fg "$1" --noise zero
  # the reference implementation as released (../shared/notes/gman-reference-facts.md): z = 0,
  # G frozen (outer and inner loop), D at its pre-trained weights (its ascent rate α1 = 0), the
  # inner step on the actor head only, on the reference's loss ‖Σ_t a_t (−D(x_t))‖₂; the inner
  # rate of the gman row
  run gman-ref gman-fixed-g "$1" --inner-lr 0.01 --disc-lr 0 --noise zero --adapt-head-only \
    --adapt-loss reference
}
extra_rows() {
  run gman-ps gman-ps "$1" --inner-lr 0.01 --ps "$R/ps/ps.ckpt"
  run gman-noemd-ps gman-noemd-ps "$1" --ps "$R/ps/ps.ckpt"
  # the ceiling at the same budget: A3C+FG given the target's true feature (docs/ceilings.md)
  run privileged a3c-fg "$1" --privileged-feature
  run gman-cossim gman-cossim "$1" --inner-lr 0.01
  run a3c-ps a3c-ps "$1" --ps "$R/ps/ps.ckpt"
  run a3c-fg-ps a3c-fg-ps "$1" --ps "$R/ps/ps.ckpt"
}
for s in $SEEDS; do
  main_rows "$s"
  case " $EXTRA_SEEDS " in *" $s "*) extra_rows "$s" ;; esac
done
# table PNG ROW...: the table of the rows that have results so far (a partial sweep has not
# made every row's folder yet), and every seed's SR with each row's mean ± std in PNG.
table() {
  local png=$1 have=()
  shift
  for r in "$@"; do [ -d "$R/$r" ] && have+=("$R/$r"); done
  [ ${#have[@]} -eq 0 ] || $G table --runs "${have[@]}" --png "$png"
}
table "$R/seeds-main.png" gman gman-adaptoff gman-noemd a3c-fg gman-nometa a3c random
table "$R/seeds-zero.png" gman-zero gman-zero-adaptoff gman-noemd-zero a3c-fg-zero gman gman-noemd a3c-fg
table "$R/seeds-other.png" privileged gman-cossim gman-cossim-adaptoff gman-ps gman-ps-adaptoff gman-noemd-ps a3c-ps a3c-fg-ps
for g in gman gman-noemd a3c-fg a3c gman-zero gman-noemd-zero a3c-fg-zero privileged gman-cossim gman-ps gman-noemd-ps a3c-ps a3c-fg-ps; do
  if ls -d "$R"/runs/$g-s[0-9]* >/dev/null 2>&1; then printf '%s\n' "$R"/runs/$g-s[0-9]*; fi
done | xargs $G plot --by-method --png "$R/curves.png" --run
