#!/usr/bin/env bash
# Parity with the authors' TransAM loop on Spread (docs/results/parity/README.md).
#
# TransAM with the authors' loop (--preset authors) and with our defaults (since 2026-12-01
# the same loop with their action-loss bug fixed; since 2026-12-02 with the policy clock too),
# against the authors' Spread population, 3 vmapped seeds each, 625k steps (the defaults run
# anneals over 10M steps like the preset: it is the first 625k steps of a default 10M run),
# an evaluation every 25k steps (1000 episodes' worth) on 100 episodes; then the figure of
# both against the authors' measured curve (CURVE:
# not part of the repository, see docs/results/parity/README.md) in docs/results/parity/.
# Set EARLIER=1 to add a run with our earlier defaults (--preset 2026-11).
#
# Before: import the population,
#   transam partners import-authors spread PATH --out runs/authors-pop
# Run from the repository root:
#   docs/results/scripts/parity.sh                 the long runs (hours on 2 CPU cores)
#   SMOKE=1 docs/results/scripts/parity.sh         5k steps, 2 seeds, our default population
# Re-running resumes unfinished runs and skips finished ones. Environment overrides:
#   TRANSAM (command), PARTNERS, OUT, STEPS, SEEDS, EVAL_EVERY (episodes), EVAL_EPISODES,
#   CURVE (the authors' curve.csv; several, space-separated, one per seed), FIGURES (output
#   folder), OURS_EXTRA (extra flags for the run with our defaults).
set -euo pipefail

TRANSAM=${TRANSAM:-transam}
if [[ -n "${SMOKE:-}" ]]; then
  PARTNERS=${PARTNERS:-default}
  OUT=${OUT:-runs/parity-smoke}
  STEPS=${STEPS:-5000}
  SEEDS=${SEEDS:-2}
  EVAL_EVERY=${EVAL_EVERY:-100}
  EVAL_EPISODES=${EVAL_EPISODES:-20}
  FIGURES=${FIGURES:-$OUT/figures}
else
  PARTNERS=${PARTNERS:-runs/authors-pop}
  OUT=${OUT:-runs/parity}
  STEPS=${STEPS:-625000}
  SEEDS=${SEEDS:-3}
  EVAL_EVERY=${EVAL_EVERY:-1000}
  EVAL_EPISODES=${EVAL_EPISODES:-100}
  FIGURES=${FIGURES:-docs/results/parity}
fi
CURVE=${CURVE:-../shared/reference/authors-loop/curve.csv}
[[ -f "${CURVE%% *}" ]] || CURVE=/work/shared/reference/authors-loop/curve.csv
HERE=$(dirname "$0")

train() {  # train NAME [flags...]: one run directory per variant, resumed when unfinished
  local name=$1
  shift
  local dir="$OUT/$name" resume=()
  [[ -f "$dir/config.json" ]] && resume=(--resume)
  echo "== $name: $dir"
  "$TRANSAM" train --env spread --method transam --partners "$PARTNERS" \
    --total-steps "$STEPS" --num-seeds "$SEEDS" \
    --eval.every-episodes "$EVAL_EVERY" --eval.episodes "$EVAL_EPISODES" \
    --out "$dir" --no-progress "${resume[@]}" "$@"
}

train authors --preset authors
# shellcheck disable=SC2086  # OURS_EXTRA is a list of flags
train defaults --a2c.anneal-steps 10000000 ${OURS_EXTRA:-}
runs=("ours, --preset authors=$OUT/authors" "our defaults=$OUT/defaults")
if [[ -n "${EARLIER:-}" ]]; then
  train earlier --preset 2026-11 --a2c.anneal-steps 10000000
  runs+=("our earlier defaults (--preset 2026-11)=$OUT/earlier")
fi

# shellcheck disable=SC2086  # CURVE is a list of files
python "$HERE/parity_plot.py" --curve $CURVE --out "$FIGURES" "${runs[@]}"
