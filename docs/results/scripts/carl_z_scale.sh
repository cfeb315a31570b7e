#!/usr/bin/env bash
# Why CARL does not learn on Tag and LBF (docs/results/{tag,lbf}/README.md): its contrastive
# z grows all through the grid's runs (Tag: |z| 3 at 75k to 33-48 at 3M beside |o| 9.9; LBF:
# 4.5 at 100k to 30-34 at 4M beside |o| 35), while CAIL's stays small and CAIL learns.
# --a2c.z-scale 0.03 keeps the policy's view of CARL's z at about 1 or under, as on Overcooked
# (overcooked_z_scale.sh, which holds Overcooked's CARL runs). CARL_SEEDS (default 0 1 2) at
# the environment's grid budget and evaluation schedule (env_grid.sh: 40 evaluations of 100
# episodes, 500 final ones on the training and held-out partners), everything else the final
# defaults; archived without checkpoints into docs/results/ENV/z-scale/carl-z-scale/. Resumes
# where it stopped; on a new machine from the archive, where an unfinished run is kept with
# its newest checkpoint.
#
#   setsid nohup nice -n 10 docs/results/scripts/carl_z_scale.sh tag > runs/tag-z-scale.log 2>&1 &
# Before the session ends: kill -TERM the `transam train` process, wait for it to exit, then
#   ARCHIVE_ONLY=1 docs/results/scripts/carl_z_scale.sh tag && git add docs/results/tag/z-scale
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source docs/results/scripts/background.sh
ENV_NAME=${1:?usage: carl_z_scale.sh tag|lbf}
case "$ENV_NAME" in
  tag) COMMON=(--env tag --total-steps 3000000 --eval.every-episodes 1500 --eval.episodes 100) ;;
  lbf) COMMON=(--env lbf --total-steps 4000000 --eval.every-episodes 2000 --eval.episodes 100) ;;
  *) echo "unknown environment '$ENV_NAME'; valid choices: tag, lbf (Overcooked's CARL runs" \
       "are in overcooked_z_scale.sh)" >&2
     exit 2 ;;
esac
BIN=${BIN:-.venv/bin}
ARCHIVE=${ARCHIVE:-docs/results/$ENV_NAME/z-scale}
PREFIX=$ENV_NAME
FINAL_EPISODES=500
source docs/results/scripts/train_keep.sh  # run NAME SEED FLAGS...: train, evaluate, keep

for seed in ${CARL_SEEDS-0 1 2}; do run carl-z-scale "$seed" --method carl --a2c.z-scale 0.03; done
