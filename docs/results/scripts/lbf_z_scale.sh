#!/usr/bin/env bash
# Why CARL does not learn on LBF (docs/results/lbf/README.md): CARL's contrastive z grows from
# |z| 4.5 to 30-34 over the grid's 4M steps (the policy's input changes under it all along),
# while CAIL's stays at 2.6-4.7 and CAIL learns. --a2c.z-scale 0.03 keeps CARL's z at ~0.1-1,
# CAIL's size or under, as it did on Overcooked (overcooked_z_scale.sh). CARL_SEEDS (default
# 0 1 2) at the grid's budget and evaluation schedule (40 evaluations of 100 episodes, 500 final
# ones on the training and held-out partners), everything else the final defaults; archived
# without checkpoints into docs/results/lbf/z-scale/. Resumes where it stopped; on a new
# machine from the archive, where an unfinished run is kept with its newest checkpoint.
#
#   setsid nohup nice -n 10 docs/results/scripts/lbf_z_scale.sh > runs/lbf-z-scale.log 2>&1 &
# Before the session ends: kill -TERM the `transam train` process, wait for it to exit, then
#   ARCHIVE_ONLY=1 docs/results/scripts/lbf_z_scale.sh && git add docs/results/lbf/z-scale
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source docs/results/scripts/background.sh
BIN=${BIN:-.venv/bin}
ARCHIVE=${ARCHIVE:-docs/results/lbf/z-scale}
PREFIX=lbf
FINAL_EPISODES=500
COMMON=(--env lbf --total-steps 4000000 --eval.every-episodes 2000 --eval.episodes 100)
source docs/results/scripts/train_keep.sh  # run NAME SEED FLAGS...: train, evaluate, keep

for seed in ${CARL_SEEDS-0 1 2}; do run carl-z-scale "$seed" --method carl --a2c.z-scale 0.03; done
