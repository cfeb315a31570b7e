#!/usr/bin/env bash
# The paper's budget on Spread (issue 35): NAM, LIAM and TransAM, 10M steps x 3 seeds each,
# the final defaults, against the authors' own Spread population; the `paper` budget of
# `transam reproduce` (an evaluation of 100 episodes every 100k steps, the paper's 100 final
# episodes on the training and the held-out partners), one run at a time. The final
# evaluations use 500 episodes (issue 35) instead of the budget's 100 (--final-episodes).
#
# It takes about 30 hours of runs on 2 CPU cores (TransAM about 700 env-steps/s alone), so
# it spans sessions whose machines do not keep runs/: the grid is kept in
# docs/results/paper-budget/grid, finished runs without checkpoints and the unfinished one
# with its newest checkpoint (archive_grid --carry), and restored from there on a new machine.
#
# Run from the repository root (resumes wherever it stopped):
#   setsid nohup nice -n 5 docs/results/scripts/paper_budget.sh > runs/paper-budget.log 2>&1 &
# Before the session ends: stop it (kill -TERM the `transam reproduce` process group; the
# run in flight writes a checkpoint), then keep it:
#   ARCHIVE_ONLY=1 docs/results/scripts/paper_budget.sh && git add docs/results/paper-budget
# Needs the authors' repository's files at ../shared/reference/authors-spread (see
# docs/partners.md#bring-the-authors-spread-population); the population never enters git.
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source docs/results/scripts/background.sh  # setsid: lower its scheduling group too
BIN=${BIN:-.venv/bin}
OUT=${OUT:-runs/paper-budget}
ARCHIVE=${ARCHIVE:-docs/results/paper-budget/grid}
POP=${POP:-runs/authors-pop}
METHODS=${METHODS:-nam liam transam}
SEEDS=${SEEDS:-0 1 2}

if [[ -z "${ARCHIVE_ONLY:-}" ]]; then
  if [[ ! -f "$POP/manifest.json" ]]; then
    "$BIN/transam" partners import-authors spread ../shared/reference/authors-spread --out "$POP"
    # the memoryless levels, into its manifest: `transam report` draws them from there
    "$BIN/transam" partners diversity spread --population "$POP" --record
  fi
  if [[ ! -f "$OUT/grid.json" && -f "$ARCHIVE/grid.json" ]]; then
    mkdir -p "$(dirname "$OUT")" && cp -r "$ARCHIVE" "$OUT"   # a new machine: restore
  fi
  # shellcheck disable=SC2086  # METHODS and SEEDS are lists
  "$BIN/transam" reproduce --budget paper --envs spread --methods $METHODS --seeds $SEEDS \
    --partners "$POP" --out "$OUT" --jobs "${JOBS:-1}" --final-episodes 500
fi
"$BIN/python" docs/results/scripts/archive_grid.py --carry "$OUT" "$ARCHIVE"

# Then the same-episodes test (docs/results/paper-budget/README.md): TransAM's and LIAM's
# models scored on each other's episodes. It needs both 10M checkpoints on one machine and
# the archives keep none, so it runs where TransAM's last seed finished (its checkpoints are
# still in runs/), beside a LIAM seed 0 retrained for it (about 30 minutes alone).
LAST=$OUT/runs/spread/transam/seed_2
LIAM_OUT=${LIAM_OUT:-runs/liam-same-episodes}
SAME=docs/results/paper-budget/same-episodes.json
if [[ -z "${ARCHIVE_ONLY:-}" && -f $LAST/final.json && -d $LAST/checkpoints && ! -f $SAME ]]; then
  "$BIN/transam" reproduce --budget paper --envs spread --methods liam --seeds 0 \
    --partners "$POP" --out "$LIAM_OUT" --jobs 1 --final-episodes 500
  "$BIN/python" docs/results/scripts/archive_grid.py --carry "$LIAM_OUT" \
    docs/results/paper-budget/liam-same-episodes
  "$BIN/python" docs/results/scripts/same_episodes.py "$LAST" \
    "$LIAM_OUT/runs/spread/liam/seed_0" --episodes 500 --out runs/same-episodes.json
  cp runs/same-episodes.json "$SAME"
fi
