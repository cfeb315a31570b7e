#!/usr/bin/env bash
# CARL's policy collapses on Spread (medium grid; the critic reading z, carl-critic/). On
# Overcooked CARL's contrastive z grows to |z| ~30 and scaling it to ~1 in the policy's input
# (--a2c.z-scale 0.03) lifts CARL from 22 to 110 (docs/results/overcooked/README.md). Is the
# Spread collapse the same size effect? The grid's settings with z scaled by 0.03, seeds 0 and
# 2 (the collapsed ones), archived here without checkpoints (metrics log eval/z_norm).
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
run=docs/results/scripts/medium_run.sh
here=docs/results/medium/carl-z-scale
for s in ${SEEDS:-0 2}; do
  out=runs/carl-z/seed_$s
  [[ -n "${ARCHIVE_ONLY:-}" ]] || "$run" "$out" "train heldout" --method carl --a2c.z-scale 0.03 --seed "$s"
  [[ -f "$out/config.json" ]] || continue
  mkdir -p "$here/seed_$s"
  for f in config.json partners.json metrics.jsonl final.json eval_train.json eval_heldout.json; do
    [[ -f "$out/$f" ]] && cp "$out/$f" "$here/seed_$s/"
  done
done
