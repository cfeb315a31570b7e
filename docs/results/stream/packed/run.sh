#!/usr/bin/env bash
# Issue 18: the streaming model (packed masks, the final defaults with the clock) at the medium
# grid's settings, 2 seeds, to set beside the grid's window TransAM. Resumable: re-run.
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source .venv/bin/activate
for s in 0 1; do
  d=runs/stream-packed/seed_$s
  if [ ! -f $d/final.json ]; then
    resume=(); [ -f $d/config.json ] && resume=(--resume)
    transam train --env spread --method transam --model.attention stream --total-steps 1000000 \
      --seed $s --eval.every-episodes 1000 --eval.episodes 100 --out $d "${resume[@]}"
  fi
  for p in train heldout; do
    [ -f $d/eval_$p.json ] || transam evaluate $d --episodes 500 --partners $p
  done
done
