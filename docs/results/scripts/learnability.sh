#!/usr/bin/env bash
# Issue 36 point 1, learnability first: NAM then the Oracle under the final defaults (plain
# `transam train`, default population), 2 vmapped seeds, on LBF, Tag and Overcooked in that
# order; each finished run `transam evaluate`d per seed on the training and the held-out
# population, then archived into docs/results/ENV/learnability/METHOD/ (config.json,
# partners.json, final.json, each seed's metrics.jsonl and eval_*.json, the train log; no
# checkpoints, TensorBoard files, figures or PCA arrays).
#
#   docs/results/scripts/learnability.sh [ENV[/METHOD[@STEPS]] ...]   # default: the chain
#
# METHOD@STEPS: a run of another length (e.g. lbf/nam@6000000 into runs/learn/lbf/nam-6m,
# archived as learnability/nam-6m), with the evaluation interval scaled to keep 25 of them.
#
# Resumable across sessions: a run already archived is skipped; an unfinished one in
# runs/learn/ENV/METHOD resumes with --resume (the machine must still have runs/learn; a new
# machine starts that run over). Niced at 10, one run at a time. Budgets (steps per seed) and
# evaluation intervals (about 25 evaluations of 100 episodes along each run) are below.
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source .venv/bin/activate

declare -A STEPS=([lbf]=3000000 [tag]=3000000 [overcooked]=1500000)
declare -A EVERY=([lbf]=2400 [tag]=2400 [overcooked]=150)  # episodes (x episode length = steps)
declare -A FINAL_EPISODES=([lbf]=500 [tag]=500 [overcooked]=200)
SEEDS=2
ROOT=${LEARN_ROOT:-runs/learn}

jobs=("$@")
[ ${#jobs[@]} -eq 0 ] && jobs=(lbf/nam lbf/oracle tag/nam tag/oracle overcooked/nam overcooked/oracle)

for job in "${jobs[@]}"; do
  env=${job%%/*}
  methods=nam\ oracle
  [ "$job" != "$env" ] && methods=${job#*/}
  for m in $methods; do
    steps=${STEPS[$env]} every=${EVERY[$env]} name=$m
    if [[ $m == *@* ]]; then
      steps=${m#*@} m=${m%@*}
      every=$((EVERY[$env] * steps / STEPS[$env])) name=$m-$((steps / 1000000))m
    fi
    out=$ROOT/$env/$name
    dest=docs/results/$env/learnability/$name
    if [ -f "$dest/final.json" ]; then
      echo "$env/$name: archived in $dest, skipped"
      continue
    fi
    mkdir -p "$(dirname "$out")"
    if [ ! -f "$out/final.json" ]; then
      resume=()
      [ -f "$out/config.json" ] && resume=(--resume)
      echo "$env/$name: training into $out ${resume[*]} ($(date -u +%FT%TZ))"
      nice -n 10 transam train --env "$env" --method "$m" --total-steps "$steps" \
        --num-seeds "$SEEDS" --eval.every-episodes "$every" --no-progress \
        --out "$out" "${resume[@]}" >> "$out.train.log" 2>&1
    fi
    for s in $(seq 0 $((SEEDS - 1))); do
      for p in train heldout; do
        if [ ! -f "$out/seed_$s/eval_$p.json" ]; then
          echo "$env/$name: evaluating seed $s on $p ($(date -u +%FT%TZ))"
          nice -n 10 transam evaluate "$out/seed_$s" --episodes "${FINAL_EPISODES[$env]}" \
            --partners "$p" >> "$out.evaluate.log" 2>&1
        fi
      done
    done
    mkdir -p "$dest"
    cp "$out"/{config.json,partners.json} "$dest/"
    cp "$out.train.log" "$dest/train.log"
    cp "$out.evaluate.log" "$dest/evaluate.log"
    for s in $(seq 0 $((SEEDS - 1))); do
      mkdir -p "$dest/seed_$s"
      cp "$out/seed_$s"/metrics.jsonl "$out/seed_$s"/eval_*.json "$dest/seed_$s/"
    done
    cp "$out/final.json" "$dest/final.json"  # last: the archive is complete
    echo "$env/$name: archived in $dest ($(date -u +%FT%TZ))"
    if [ -z "${NO_COMMIT:-}" ]; then
      for try in 1 2 3 4 5 6 7 8 9 10; do
        if [ ! -e .git/index.lock ] && git add "$dest" &&
          git commit -q -m "learnability: $env/$name archived ($steps steps x $SEEDS seeds, final defaults, default population; docs/results/scripts/learnability.sh)" -- "$dest"; then
          break
        fi
        sleep 5
      done
    fi
  done
done
