#!/usr/bin/env bash
# Issue 20 hypothesis: does a whole-episode memory (75 tokens = 25 steps) raise the stream
# model's partner-action accuracy over its 15-token default? 1 seed, medium-grid settings.
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source .venv/bin/activate
d=runs/stream-mem75/seed_0
if [ ! -f $d/final.json ]; then
  resume=(); [ -f $d/config.json ] && resume=(--resume)
  transam train --env spread --method transam --model.attention stream --model.memory 75 \
    --total-steps 1000000 --seed 0 --eval.every-episodes 1000 --eval.episodes 100 --out $d "${resume[@]}"
fi
for p in train heldout; do
  [ -f $d/eval_$p.json ] || transam evaluate $d --episodes 500 --partners $p
done
