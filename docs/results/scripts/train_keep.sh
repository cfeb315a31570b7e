# Sourced by the single-run studies (overcooked_z_scale.sh, carl_z_scale.sh). `run NAME SEED
# FLAGS...` trains runs/$PREFIX-NAME-sSEED (or resumes it), evaluates it on the training and
# the held-out partners ($FINAL_EPISODES episodes each) and keeps it in $ARCHIVE/NAME/seed_SEED
# without checkpoints (an unfinished run with its newest one), whence a new machine restores
# it. With ARCHIVE_ONLY set it only keeps. Needs BIN, ARCHIVE, PREFIX, COMMON (train flags).
FINAL_EPISODES=${FINAL_EPISODES:-200}

keep() {  # NAME SEED: the run into the archive; an unfinished one with its newest checkpoint
  local out=runs/$PREFIX-$1-s$2 kept=$ARCHIVE/$1/seed_$2
  [[ -f "$out/config.json" ]] || return 0
  rm -rf "$kept" && mkdir -p "$kept"
  for f in config.json partners.json metrics.jsonl final.json eval_train.json eval_heldout.json; do
    [[ -f "$out/$f" ]] && cp "$out/$f" "$kept/"
  done
  if [[ ! -f "$out/eval_heldout.json" ]]; then
    local newest
    newest=$(find "$out/checkpoints" -name 'chunk_*.msgpack' 2>/dev/null | sort | tail -n 1)
    [[ -n "$newest" ]] && mkdir -p "$kept/checkpoints" && cp "$newest" "$kept/checkpoints/"
  fi
  return 0
}

run() {  # NAME SEED FLAGS...: train (or resume), evaluate, archive
  local name=$1 seed=$2 out=runs/$PREFIX-$1-s$2
  shift 2
  if [[ -n "${ARCHIVE_ONLY:-}" ]]; then keep "$name" "$seed"; return 0; fi
  if [[ ! -e "$out" && -f "$ARCHIVE/$name/seed_$seed/config.json" ]]; then
    mkdir -p runs && cp -r "$ARCHIVE/$name/seed_$seed" "$out"   # a new machine: restore
  fi
  if [[ ! -f "$out/final.json" ]]; then
    local resume=()
    [[ -f "$out/config.json" ]] && resume=(--resume)
    "$BIN/transam" train "${COMMON[@]}" --seed "$seed" "$@" --out "$out" "${resume[@]}"
  fi
  [[ -f "$out/eval_train.json" ]] || "$BIN/transam" evaluate "$out" --episodes "$FINAL_EPISODES"
  [[ -f "$out/eval_heldout.json" ]] ||
    "$BIN/transam" evaluate "$out" --episodes "$FINAL_EPISODES" --partners heldout
  keep "$name" "$seed"
}
