#!/usr/bin/env bash
# Issue 20 diagnostic: is TransAM's accuracy gap to LIAM its training target? recon_at
# "window" (the authors': every window position, mostly easy older ones) vs "last" (only the
# newest, as LIAM decodes), with the policy frozen (a2c lr 1e-9) so only the agent model
# learns on the same data distribution; 200k steps, seed 0, our default population.
# Resumable: finished runs are skipped.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
source .venv/bin/activate

for v in "window|--method transam" "last|--method transam --model.recon-at last" "liam|--method liam"; do
  name=${v%%|*}; flags=${v#*|}
  d=runs/recon-diag/$name
  [ -f $d/final.json ] && continue
  resume=(); [ -f $d/config.json ] && resume=(--resume)
  # shellcheck disable=SC2086
  transam train --env spread $flags --a2c.lr 1e-9 --total-steps 200000 --seed 0 \
    --eval.every-episodes 1000 --eval.episodes 100 --out $d --no-progress "${resume[@]}"
done
