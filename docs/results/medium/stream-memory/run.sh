#!/usr/bin/env bash
# Issue 20 hypothesis: does a whole-episode memory (75 tokens = 25 steps) raise the stream
# model's partner-action accuracy over its 15-token default? 1 seed, medium-grid settings.
set -euo pipefail
"$(dirname "$0")/../../scripts/medium_run.sh" runs/stream-mem75/seed_0 "train heldout" \
  --method transam --model.attention stream --model.memory 75 --seed 0
