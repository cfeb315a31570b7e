#!/usr/bin/env bash
# Issue 20 point 3: CARL's policy collapses in the medium grid (entropy 1.60 -> 0.68, below
# random play). Is it the critic reading z again (docs/notes/2026-11-encoder-collapse-critic-z.md)?
# The grid's settings with the critic on its own trunk, seeds 0 and 2 (the collapsed ones).
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source .venv/bin/activate
for s in 0 2; do
  d=runs/carl-nocz/seed_$s
  if [ ! -f $d/final.json ]; then
    resume=(); [ -f $d/config.json ] && resume=(--resume)
    transam train --env spread --method carl --a2c.no-critic-z --total-steps 1000000 --seed $s \
      --eval.every-episodes 1000 --eval.episodes 100 --out $d "${resume[@]}"
  fi
  [ -f $d/eval_train.json ] || transam evaluate $d --episodes 500 --partners train
done
