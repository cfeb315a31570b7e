#!/usr/bin/env bash
# The grid of one environment beyond Spread (issue 36, point 2): TransAM, LIAM, NAM and the
# Oracle x 3 seeds (the four methods the issue asks for first) at the budget the
# environment's learnability study chose, the final defaults, against its default
# population; every run then evaluated on the training and the held-out partners, and
# `transam report` built. One run at a time: the cheap methods first, so that a session
# that ends early has whole comparisons, TransAM last.
#
#   Tag          3M steps  (docs/results/tag/README.md: learns within 3M, NAM and the Oracle
#                           7 apart), an evaluation of 100 episodes every 75k steps
#   Overcooked   1.5M steps (learns within 1-1.5M; the evaluations of 400-step episodes
#                           cost as much as training: 25 of 100 episodes, 200 final ones)
#   LBF          4M steps  (every seed reaches the plateau, which is A2C's: docs/results/lbf)
#   spread       the medium grid (docs/results/medium/README.md): all ten methods, the
#                `medium` budget as it is (1M steps), archived in docs/results/medium/grid
#
# It spans sessions whose machines do not keep runs/: the grid is kept in
# docs/results/ENV/grid, finished runs without checkpoints and an unfinished one with its
# newest checkpoint (archive_grid --carry), and restored from there on a new machine.
#
# Run from the repository root (resumes wherever it stopped):
#   setsid nohup nice -n 10 docs/results/scripts/env_grid.sh tag > runs/grid-tag.log 2>&1 &
# Before the session ends: stop it (kill -TERM its `transam reproduce` process; the run in
# flight writes a checkpoint), then keep it:
#   ARCHIVE_ONLY=1 docs/results/scripts/env_grid.sh tag && git add docs/results/tag/grid
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source docs/results/scripts/background.sh  # setsid: lower its scheduling group too
ENV_NAME=${1:?usage: env_grid.sh tag|overcooked|lbf|spread}
BIN=${BIN:-.venv/bin}
OUT=${OUT:-runs/grid-$ENV_NAME}
if [[ "$ENV_NAME" == spread ]]; then  # the medium grid
  ARCHIVE=${ARCHIVE:-docs/results/medium/grid}
  METHODS=${METHODS:-nam oracle liam cail pel carl transam transam-fuse transam-pool transam-im}
fi
ARCHIVE=${ARCHIVE:-docs/results/$ENV_NAME/grid}
METHODS=${METHODS:-nam oracle liam transam}
SEEDS=${SEEDS:-0 1 2}
case "$ENV_NAME" in
  tag) BUDGET=(--total-steps 3000000 --evals 40 --eval-episodes 100 --final-episodes 500) ;;
  overcooked) BUDGET=(--total-steps 1500000 --evals 25 --eval-episodes 100 --final-episodes 200) ;;
  lbf) BUDGET=(--total-steps 4000000 --evals 40 --eval-episodes 100 --final-episodes 500) ;;
  spread) BUDGET=() ;;
  *) echo "unknown environment '$ENV_NAME'; valid choices: tag, overcooked, lbf, spread" >&2
     exit 2 ;;
esac

if [[ -z "${ARCHIVE_ONLY:-}" ]]; then
  if [[ ! -f "$OUT/grid.json" && -f "$ARCHIVE/grid.json" ]]; then
    mkdir -p "$(dirname "$OUT")" && cp -r "$ARCHIVE" "$OUT"   # a new machine: restore
  fi
  # shellcheck disable=SC2086  # METHODS and SEEDS are lists
  "$BIN/transam" reproduce --budget medium --envs "$ENV_NAME" --methods $METHODS \
    --seeds $SEEDS --out "$OUT" --jobs 1 "${BUDGET[@]}"
fi
"$BIN/python" docs/results/scripts/archive_grid.py --carry "$OUT" "$ARCHIVE"
