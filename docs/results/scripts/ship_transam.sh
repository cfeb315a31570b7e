#!/usr/bin/env bash
# The TransAM that `make demo` ships (issue 35, point 3): the final defaults, our default
# Spread population (the shipped one, so the weights are ours to ship), seed 0, 5M steps
# (the learning rate annealed over 5M), an evaluation of 100 episodes every 100k steps: the
# budget and settings of the shipped NAM and Oracle.
#
# It takes about 2 hours alone on 2 cores, longer beside other work, so it may span
# sessions whose machines do not keep runs/. ARCHIVE keeps the run's config, population
# record and metrics, and, while it is unfinished, its newest checkpoint (about 8 MB); a new
# machine restores the run from there and resumes.
#   setsid nohup nice -n 5 docs/results/scripts/ship_transam.sh > runs/ship_transam.log 2>&1 &
#   STOP=1 docs/results/scripts/ship_transam.sh    # stop it (a checkpoint is kept) and archive
# When it has finished: export it over src/transam/pretrained/spread-transam (`transam export
# runs/spread-transam-5m --out ...`) and measure its gain with paired_gain.py.
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
source docs/results/scripts/background.sh  # setsid: lower its scheduling group too
BIN=${BIN:-.venv/bin}
OUT=${OUT:-runs/spread-transam-5m}
ARCHIVE=${ARCHIVE:-docs/results/shipped-transam/run}

archive() {
  mkdir -p "$ARCHIVE"
  cp "$OUT"/config.json "$OUT"/partners.json "$OUT"/metrics.jsonl "$ARCHIVE"/
  [[ -f "$OUT/final.json" ]] && cp "$OUT"/final.json "$ARCHIVE"/
  rm -rf "$ARCHIVE/checkpoints"
  if [[ ! -f "$OUT/final.json" ]]; then  # unfinished: carry the newest checkpoint
    newest=$(find "$OUT/checkpoints" -name 'chunk_*.msgpack' | sort | tail -1)
    mkdir -p "$ARCHIVE/checkpoints" && cp "$newest" "$ARCHIVE/checkpoints/"
  fi
  echo "archived $OUT into $ARCHIVE"
}

if [[ -n "${STOP:-}" ]]; then
  pkill -TERM -f "transam train .*--out $OUT" || true
  while pgrep -f "transam train .*--out $OUT" > /dev/null; do sleep 2; done
  archive
  exit 0
fi
if [[ ! -f "$OUT/config.json" && -f "$ARCHIVE/config.json" ]]; then
  mkdir -p "$OUT" && cp -r "$ARCHIVE"/. "$OUT"/   # a new machine: restore
fi
resume=()
[[ -f "$OUT/config.json" ]] && resume=(--resume)
"$BIN/transam" train --env spread --method transam --partners default --total-steps 5000000 \
  --seed 0 --eval.every-episodes 4000 --eval.episodes 100 --no-progress --out "$OUT" \
  "${resume[@]}"
archive
