#!/usr/bin/env bash
# Issue 20: TransAM's accuracy trails LIAM/PEL/CAIL at 1M steps in the medium grid; the 2026-11
# note found pre-norm blocks closed half the fitting gap at 100k. Seed 0, medium-grid settings.
set -euo pipefail
"$(dirname "$0")/../../scripts/medium_run.sh" runs/transam-prenorm/seed_0 "train heldout" \
  --method transam --model.norm pre --seed 0
