#!/usr/bin/env bash
# LBF, NAM from scratch under two A2C settings that change the size of the policy's steps
# (issue 36; docs/results/lbf/README.md "Two A2C settings from scratch"): does a setting
# that makes A2C's updates gentler lift it above the 0.19 plateau? A tenth of the learning
# rate (3e-5), and four times the batch per update (40 environments instead of 10: a
# quarter of the updates for the same steps). 3M steps x 2 vmapped seeds each, the default
# population, then `transam evaluate` (500 episodes) per seed, archived into
# docs/results/lbf/a2c-settings/NAME/. Resumable; niced at 10.
#   docs/results/scripts/lbf_a2c_settings.sh   (about 20 minutes per setting on 2 cores)
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
ROOT=${ROOT:-runs/lbf-a2c}
mkdir -p "$ROOT"
for v in "lr3e-5 --a2c.lr 3e-5" "envs40 --a2c.num-envs 40"; do
  name=${v%% *} args=${v#* } out=$ROOT/${v%% *} dest=docs/results/lbf/a2c-settings/${v%% *}
  if [[ ! -f "$out/final.json" ]]; then
    resume=() && [[ -f "$out/config.json" ]] && resume=(--resume)
    echo "$name: training ($(date -u +%FT%TZ))"
    # shellcheck disable=SC2086  # args is a list of options
    nice -n 10 .venv/bin/transam train --env lbf --method nam --total-steps 3000000 \
      --num-seeds 2 --eval.every-episodes 2400 --no-progress --out "$out" $args \
      "${resume[@]}" >> "$out.train.log" 2>&1
  fi
  for s in 0 1; do
    [[ -f "$out/seed_$s/eval_train.json" ]] || nice -n 10 .venv/bin/transam evaluate \
      "$out/seed_$s" --episodes 500 --partners train >> "$out.evaluate.log" 2>&1
    mkdir -p "$dest/seed_$s"
    cp "$out/seed_$s"/{metrics.jsonl,eval_train.json} "$dest/seed_$s/"
  done
  cp "$out"/{config.json,partners.json,final.json} "$dest/" && cp "$out.train.log" "$dest/train.log"
done
