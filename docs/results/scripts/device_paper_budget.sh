#!/usr/bin/env bash
# The paper budget's TransAM runs (issue 35) on a lent GPU machine, for the minutes a session
# has one: seed 0 resumed from its carried checkpoint, seeds 1 and 2 from the start, three
# processes side by side on the one GPU, each stopped with SIGTERM after $TRAIN_S seconds
# (it checkpoints at its next chunk boundary). Each run comes back as a tarball (checkpoints
# included) to be merged into runs/paper-budget with merge_device_runs.py, where the CPU grid
# (paper_budget.sh) resumes it. Also records GPU utilisation and the runs' progress (metrics
# lines, one per 100k-step chunk, with a timestamp) for the throughput figure.
#
# The machine has its own JAX (0.11.x, CUDA 13) but lacks jaxmarl and tyro: those travel as
# wheels in .whl/ (pip download ... jaxmarl==0.2.0 tyro==1.0.17 docstring-parser
# typeguard==4.6.1), and the population in runs/authors-pop (carry both). The grid records the
# population's absolute path (/work/main/runs/authors-pop), so it is put at that path there.
# float32 matmuls run at full precision (JAX_DEFAULT_MATMUL_PRECISION=highest), as on CPU,
# not in TF32. Run in the repository root on that machine:
#   TRAIN_S=450 bash docs/results/scripts/device_paper_budget.sh
set -uo pipefail
TRAIN_S=${TRAIN_S:-450}
OUT=${OUT:-/tmp/device-out}
mkdir -p "$OUT"
PY=${PY:-python3}  # PY=.venv/bin/python JAX_PLATFORMS=cpu NO_WHEELS=1: a dry run on CPU
[[ -n "${NO_WHEELS:-}" ]] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --no-cache-dir --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1 JAX_PLATFORMS=${JAX_PLATFORMS:-cuda}
export XLA_PYTHON_CLIENT_PREALLOCATE=false JAX_DEFAULT_MATMUL_PRECISION=highest
POP=/work/main/runs/authors-pop
if [[ ! -f $POP/manifest.json ]]; then mkdir -p /work/main/runs && cp -r runs/authors-pop $POP; fi
nvidia-smi -L 2>/dev/null
"$PY" -c "import jax, flax, optax, chex; print('jax', jax.__version__, 'flax', flax.__version__,
'optax', optax.__version__, 'chex', chex.__version__, jax.devices())" || exit 1

mkdir -p runs && rm -rf runs/pb0 runs/pb1 runs/pb2
cp -r docs/results/paper-budget/grid runs/pb0  # seed 0, carried with its newest checkpoint
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 10 \
  > "$OUT/gpu.csv" 2>&1 &
smi=$!
pids=()
for s in 0 1 2; do
  timeout -s TERM -k "${KILL_AFTER:-90}" "$TRAIN_S" "$PY" -c \
    'import sys; from transam.cli import main; sys.argv[0] = "transam"; main()' \
    reproduce --budget paper --envs spread --methods transam --seeds $s --partners $POP \
    --out runs/pb$s --jobs 1 --final-episodes 500 > "$OUT/pb$s.log" 2>&1 &
  pids+=($!)
done
(while sleep 10; do
  echo "$(date +%s) $(for s in 0 1 2; do
    wc -l < runs/pb$s/runs/spread/transam/seed_$s/metrics.jsonl 2>/dev/null || echo 0; done |
    tr '\n' ' ')"
done) > "$OUT/progress.txt" &
poll=$!
wait "${pids[@]}"
kill $poll $smi 2>/dev/null
for s in 0 1 2; do
  tar czf "$OUT/pb$s.tgz" -C runs/pb$s grid.json log runs/spread/transam/seed_$s
done
ls -la "$OUT"; tail -n 5 "$OUT"/pb*.log; tail -n 3 "$OUT/progress.txt"
