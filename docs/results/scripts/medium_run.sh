#!/usr/bin/env bash
# One run at the medium grid's settings (1M steps, an evaluation of 100 episodes every 25k
# steps), trained or resumed into OUT, then `transam evaluate`d with 500 episodes on each
# partner set in PARTNERS not yet evaluated: what `transam reproduce` does for a grid run, for
# the side runs set beside the grid. Resumable: run it again.
#   medium_run.sh OUT "train heldout" --method transam --seed 0 [more `transam train` args]
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 OUT PARTNERS [transam train args]; PARTNERS: 'train', 'heldout' or both" >&2
  exit 2
fi
out=$1 partners=$2
shift 2
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source .venv/bin/activate
if [ ! -f "$out/final.json" ]; then
  resume=()
  [ -f "$out/config.json" ] && resume=(--resume)
  transam train --env spread --total-steps 1000000 --eval.every-episodes 1000 \
    --eval.episodes 100 --out "$out" "$@" "${resume[@]}"
fi
for p in $partners; do
  [ -f "$out/eval_$p.json" ] || transam evaluate "$out" --episodes 500 --partners "$p"
done
