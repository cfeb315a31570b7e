#!/usr/bin/env bash
# Grids' runs on a lent GPU machine, for the minutes a session has one (issues 35, 36): each
# entry of RUNS ("METHOD:SEED ...", at most 6 in all; "METHOD:S1,S2" trains those seeds as
# one vmapped program, --vmap-seeds) in its own `transam reproduce` process, side by side on
# the one GPU (the program is latency-bound: docs/performance.md#on-a-gpu), each
# started from its grid's archive (ARCHIVE: a carried run resumes from its checkpoint; none
# there, a new grid) and stopped with SIGTERM after TRAIN_S seconds (it checkpoints at its
# next chunk boundary). Each run comes back as $OUT/runK-GRID.tgz (GRID: the archive's folder
# name, e.g. paper-budget or tag; grid.json, log/, the run with its newest checkpoint,
# console$K.log) to be merged into that grid on the CPU with merge_device_runs.py, which
# resumes it there. gpu.csv and progress.txt (metrics lines, one per chunk, polled every 10 s)
# give the throughput. What comes back is at most 8 files of 16 MiB, 64 MiB in all: a
# TransAM checkpoint is about 8 MB (7.8 gzipped), so 6 runs, or a vmapped pair per entry.
#
# The working tree travels (tracked and untracked files, plus what `carry` names: at most
# 64 MiB). Without the carried checkpoints it is about 21 MB; each carried TransAM checkpoint
# in docs/results/*/grid adds 8.4 MB, so 5 of them fit beside the wheels. Before a call,
# delete from the working tree the carried checkpoints of runs the call does not train, and
# restore them afterwards from git (`git checkout -- docs/results`); check the size with
#   (git ls-files -co --exclude-standard; find .whl runs/authors-pop -type f) | xargs du -cb | tail -1
#
# Several grids in one call: GRIDS, one line per grid, "ARCHIVE | ARGS | RUNS" (as the
# variables of those names give one grid); without GRIDS, the one grid ARCHIVE, ARGS, RUNS.
#
# The machine has its own JAX (0.11.x, CUDA 13) but lacks jaxmarl and tyro: those travel as
# wheels in .whl/ (pip download --no-deps --python-version 3.12 ... jaxmarl==0.2.0
# tyro==1.0.17 docstring-parser typeguard==4.6.1; carry .whl). A population directory given
# as --partners /work/main/runs/NAME (grids record its absolute path) travels as runs/NAME
# (carry it too) and is put at that path there. float32 matmuls run at full precision
# (JAX_DEFAULT_MATMUL_PRECISION=highest), as on CPU, not in TF32. RESUME=1 continues the
# runs a previous call left on the same (still warm) machine.
#
# The paper budget's TransAM seeds 1-2 (issue 35) and the Tag grid's TransAM seeds (issue 36)
# in one call (ARGS as the CPU script that owns each grid passes them: paper_budget.sh,
# env_grid.sh):
#   GRIDS="docs/results/paper-budget/grid | --budget paper --envs spread \
#   --partners /work/main/runs/authors-pop --final-episodes 500 | transam:1 transam:2
#   docs/results/tag/grid | --budget medium --envs tag --total-steps 3000000 --evals 40 \
#   --eval-episodes 100 --final-episodes 500 | transam:0 transam:1 transam:2" \
#   TRAIN_S=440 bash docs/results/scripts/device_grid.sh
# Then here, per grid: python docs/results/scripts/merge_device_runs.py \
#   DEVICE_FILES/run*-paper-budget.tgz --grid runs/paper-budget   (runs/grid-tag for tag)
set -uo pipefail
GRIDS=${GRIDS:-"${ARCHIVE:?set GRIDS, or ARCHIVE, ARGS and RUNS} | ${ARGS:?} | ${RUNS:?}"}
TRAIN_S=${TRAIN_S:-440}
OUT=${OUT:-/tmp/device-out}
PY=${PY:-python3}  # PY=.venv/bin/python JAX_PLATFORMS=cpu NO_WHEELS=1: a dry run on CPU
trim() { sed 's/^ *//; s/ *$//' <<< "$1"; }
# one entry per process: its grid's archive, its ARGS, its METHOD:SEEDS
archives=() argsets=() runs=()
while IFS= read -r line; do
  [[ -z "$(trim "$line")" ]] && continue
  IFS='|' read -r archive grid_args grid_runs <<< "$line"
  archive=$(trim "$archive") grid_args=$(trim "$grid_args")
  [[ -n "$archive" && -n "$grid_args" && -n "$(trim "$grid_runs")" ]] ||
    { echo "GRIDS line '$line': want 'ARCHIVE | ARGS | RUNS'" >&2; exit 2; }
  for r in $grid_runs; do archives+=("$archive") argsets+=("$grid_args") runs+=("$r"); done
done <<< "$GRIDS"
((${#runs[@]} <= 6)) || { echo "at most 6 runs in all (8 files come back)" >&2; exit 2; }
mkdir -p "$OUT" runs
[[ -n "${NO_WHEELS:-}" ]] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1 JAX_PLATFORMS=${JAX_PLATFORMS:-cuda}
export XLA_PYTHON_CLIENT_PREALLOCATE=false JAX_DEFAULT_MATMUL_PRECISION=highest
for grid_args in "${argsets[@]}"; do
  if [[ "$grid_args" =~ --partners\ (/work/main/(runs/[^ ]+)) && ! -d "${BASH_REMATCH[1]}" ]]; then
    mkdir -p "$(dirname "${BASH_REMATCH[1]}")" && cp -r "${BASH_REMATCH[2]}" "${BASH_REMATCH[1]}"
  fi
done
nvidia-smi -L 2>/dev/null
"$PY" -c "import jax, flax, optax; print('jax', jax.__version__, 'flax', flax.__version__,
'optax', optax.__version__, jax.devices())" || exit 1
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 10 \
  > "$OUT/gpu.csv" 2>&1 &
smi=$!
pids=() rels=() names=()
for k in "${!runs[@]}"; do
  read -r -a args <<< "${argsets[$k]}"
  env=$(sed -n 's/.*--envs \([a-z]*\).*/\1/p' <<< "${argsets[$k]}")
  name=${archives[$k]%/} && [[ "$(basename "$name")" == grid ]] && name=$(dirname "$name")
  names+=("$(basename "$name")")
  method=${runs[$k]%:*} seeds=${runs[$k]#*:}  # METHOD:S1,S2: one vmapped program (--vmap-seeds)
  read -r -a seed_list <<< "${seeds//,/ }"
  vmap=() && ((${#seed_list[@]} > 1)) && vmap=(--vmap-seeds)
  rels+=("$(printf "runs/$env/$method/seed_%s " "${seed_list[@]}")")
  if [[ -z "${RESUME:-}" ]]; then
    rm -rf "runs/dev$k"
    if [[ -d "${archives[$k]}" ]]; then cp -r "${archives[$k]}" "runs/dev$k"; fi
  fi
  timeout -s TERM -k "${KILL_AFTER:-90}" "$TRAIN_S" "$PY" -c \
    'import sys; from transam.cli import main; sys.argv[0] = "transam"; main()' \
    reproduce "${args[@]}" --methods "$method" --seeds "${seed_list[@]}" "${vmap[@]}" \
    --out "runs/dev$k" --jobs 1 \
    > "runs/console$k.log" 2>&1 &
  pids+=($!)
done
(while sleep 10; do
  echo "$(date +%s) $(for k in "${!runs[@]}"; do
    first=${rels[$k]%% *}
    wc -l < "runs/dev$k/$first/metrics.jsonl" 2>/dev/null || echo 0; done | tr '\n' ' ')"
done) >> "$OUT/progress.txt" &
poll=$!
wait "${pids[@]}"
kill $poll $smi 2>/dev/null
for k in "${!runs[@]}"; do
  # the newest checkpoint only: a file over 16 MiB would not come back
  read -r -a rel_list <<< "${rels[$k]}"
  for rel in "${rel_list[@]}"; do
    find "runs/dev$k/$rel" -name '*.msgpack' | sort | head -n -1 | xargs -r rm
  done
  tgz="$OUT/run$k-${names[$k]}.tgz"
  tar czf "$tgz" --exclude=.lock -C "runs/dev$k" grid.json log "${rel_list[@]}" \
    -C .. "console$k.log"
  echo "== ${names[$k]} ${runs[$k]}: $(du -h "$tgz" | cut -f1)"; tail -n 4 "runs/console$k.log"
  (($(stat -c %s "$tgz") < 16 * 1024 * 1024)) || echo "WARNING: $tgz is over 16 MiB: it will not come back"
done
tail -n 2 "$OUT/progress.txt"
