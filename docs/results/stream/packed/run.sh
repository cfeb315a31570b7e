#!/usr/bin/env bash
# Issue 18: the streaming model (packed masks, the final defaults with the clock) at the medium
# grid's settings, 2 seeds, to set beside the grid's window TransAM. Resumable: re-run.
set -euo pipefail
run="$(dirname "$0")/../../scripts/medium_run.sh"
for s in 0 1; do
  "$run" runs/stream-packed/seed_$s "train heldout" --method transam \
    --model.attention stream --seed $s
done
