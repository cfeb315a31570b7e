#!/usr/bin/env bash
# The deviation table (docs/results/parity/README.md): each of our departures from the
# authors' loop, measured one at a time against the preset. Every run is `--preset authors`
# with ONE setting put back to our earlier default (--preset 2026-11); same population, seeds,
# length and evaluation as parity.sh, whose `authors` run is the baseline (run parity.sh
# first, or set BASELINE). The action-loss fix is parity.sh's `defaults` run (the defaults are
# the preset with that one fix), read from PARITY. Then the table.
#
#   docs/results/scripts/deviations.sh                  all rows (13 runs of 3 seeds: long)
#   ONLY="clock critic_no_z" docs/results/scripts/deviations.sh     some rows
#   SMOKE=1 docs/results/scripts/deviations.sh          5k steps, 2 seeds, default population
#   PRESET=none ONLY=gae_advantage docs/results/scripts/deviations.sh
#                       the row on top of the final defaults (the preset with the action loss
#                       fixed, and the clock) instead of the preset: outputs in
#                       runs/deviations-defaults, baseline runs/parity/defaults (parity.sh's run
#                       of the current defaults), table deviations-final.md
#   PRESET=none ONLY=model_lr_1e3 docs/results/scripts/deviations.sh
#                       a candidate (CANDIDATES below: a setting that was never a default) on
#                       top of the final defaults
# Re-running resumes unfinished runs and skips finished ones. Overrides as in parity.sh, plus
# BASELINE (the preset run) and TABLE (output markdown). Every row's curves are kept beside the
# table (TABLE with .csv for .md): a row run once stays in the table when later runs of this
# script select others, and the run directories may then be deleted.
set -euo pipefail

TRANSAM=${TRANSAM:-transam}
PRESET=${PRESET:-authors}
if [[ -n "${SMOKE:-}" ]]; then
  PARTNERS=${PARTNERS:-default}
  OUT=${OUT:-runs/deviations-smoke}
  STEPS=${STEPS:-5000}
  SEEDS=${SEEDS:-2}
  EVAL_EVERY=${EVAL_EVERY:-100}
  EVAL_EPISODES=${EVAL_EPISODES:-20}
  BASELINE=${BASELINE:-runs/parity-smoke/authors}
  PARITY=${PARITY:-runs/parity-smoke}
  TABLE=${TABLE:-$OUT/deviations.md}
else
  PARTNERS=${PARTNERS:-runs/authors-pop}
  if [[ $PRESET == none ]]; then
    OUT=${OUT:-runs/deviations-defaults}
    BASELINE=${BASELINE:-runs/parity/defaults}
    TABLE=${TABLE:-docs/results/parity/deviations-final.md}
  fi
  OUT=${OUT:-runs/deviations}
  STEPS=${STEPS:-625000}
  SEEDS=${SEEDS:-3}
  EVAL_EVERY=${EVAL_EVERY:-1000}
  EVAL_EPISODES=${EVAL_EPISODES:-100}
  BASELINE=${BASELINE:-runs/parity/authors}
  PARITY=${PARITY:-runs/parity}
  TABLE=${TABLE:-docs/results/parity/deviations.md}
fi
HERE=$(dirname "$0")

# name | flags that put one setting back to our default
ROWS=(
  "update_every_rollout|--a2c.rollouts-per-collect 1"
  "gae_advantage|--a2c.advantage gae"
  "half_value_loss|--a2c.value-loss half_squared"
  "terminal_time_limit|--a2c.end-bootstrap zero"
  "anneal_over_run|--a2c.anneal-steps 0"
  "orthogonal_init|--a2c.init orthogonal"
  "no_act_dropout|--a2c.no-act-dropout --a2c.z-pass separate"
  "acting_z|--a2c.no-recompute-z"
  "critic_no_z|--a2c.no-critic-z"
  "clock|--a2c.time-feature"
  "token_layernorm|--model.embed-ln"
  "flax_init|--model.init default"
  "recon_in_rollout|--model.recon-at all"
)
# name | flags of a setting that was never a default: a candidate measured against the final
# defaults only (PRESET=none), and only when named in ONLY
CANDIDATES=(
  "model_lr_1e3|--a2c.model-lr 1e-3"
  "model_passes_2|--a2c.model-passes 2"
  "z_scale_unit|--a2c.z-scale 0.088"
)

selected() {
  [[ -z "${ONLY:-}" ]] && return 0
  [[ " $ONLY " == *" $1 "* ]]
}

args=()
if [[ $PRESET != none ]] && selected proper_action_ce && [[ -f "$PARITY/defaults/config.json" ]]; then
  args+=("proper_action_ce (--model.action-loss ce, the defaults)=$PARITY/defaults")
fi
candidates=()
if [[ $PRESET == none && -n "${ONLY:-}" ]]; then
  candidates=("${CANDIDATES[@]}")
fi
for row in "${ROWS[@]}" "${candidates[@]}"; do
  name=${row%%|*}
  flags=${row#*|}
  selected "$name" || continue
  if [[ $PRESET == none && $name == clock ]]; then
    echo "== clock: a default since 2026-12-02, so on top of the defaults it is the baseline; skipped"
    continue
  fi
  dir="$OUT/$name"
  resume=()
  [[ -f "$dir/config.json" ]] && resume=(--resume)
  echo "== $name ($flags): $dir"
  # shellcheck disable=SC2086  # flags is a list
  "$TRANSAM" train --env spread --method transam --preset "$PRESET" --partners "$PARTNERS" \
    --total-steps "$STEPS" --num-seeds "$SEEDS" --a2c.anneal-steps 10000000 \
    --eval.every-episodes "$EVAL_EVERY" --eval.episodes "$EVAL_EPISODES" \
    --out "$dir" --no-progress "${resume[@]}" $flags
  args+=("$name ($flags)=$dir")
done

# the baseline's curves are kept too: without its run directory, read it from there
[[ -d $BASELINE || ! -f ${TABLE%.md}.csv ]] || BASELINE=${TABLE%.md}.csv
label="preset (authors)"
[[ $PRESET == none ]] && label="final defaults"
python "$HERE/deviation_table.py" --baseline "$BASELINE" --baseline-label "$label" \
  --out "$TABLE" --curves "${TABLE%.md}.csv" "${args[@]}"
