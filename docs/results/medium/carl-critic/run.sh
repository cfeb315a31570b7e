#!/usr/bin/env bash
# Issue 20 point 3: CARL's policy collapses in the medium grid (entropy 1.60 -> 0.68, below
# random play). Is it the critic reading z again (docs/notes/2026-11-encoder-collapse-critic-z.md)?
# The grid's settings with the critic on its own trunk, seeds 0 and 2 (the collapsed ones).
set -euo pipefail
run="$(dirname "$0")/../../scripts/medium_run.sh"
for s in 0 2; do
  "$run" runs/carl-nocz/seed_$s train --method carl --a2c.no-critic-z --seed $s
done
