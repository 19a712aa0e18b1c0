#!/usr/bin/env bash
# A thin driver of the CPU training campaign (docs/training.md): one training cycle at a time, in the
# background at the lowest priority, resumed across sessions. The recipes are the packaged TOML files
# python/mipnet/training/recipes/campaign-s*.toml (`mipnet train --config campaign-s12 ...`).
#
#   scripts/campaign.sh cycle [STEPS] [RECIPE]   # a new one-cycle run of STEPS (default 1000) with RECIPE
#                                               # (default campaign-s12) from the shipped weights (or
#                                               # INIT=weights.safetensors), in $ROOT/train/cycle-DATE; the data
#                                               # seed is the start time, or SEED=S (to pair it with an earlier run)
#   scripts/campaign.sh resume RUN              # resume the run folder RUN (a name under $ROOT/train)
#   scripts/campaign.sh stop                    # SIGTERM: the run checkpoints after its step and exits
#   scripts/campaign.sh status                  # last log lines and validation of every run
#
# The run uses a snapshot of the package (python/ and the built core) copied to ENGINE, so rebuilding or
# editing the working tree never changes the code under a running process.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${MIPNET_CAMPAIGN_ROOT:-$HOME/.cache/mipnet}
ENGINE=$ROOT/engine
PY=${PYTHON:-python}
SHIPPED=python/mipnet/assets/mipnet_pretrained.safetensors

require_idle() {
  if pgrep -f "mipnet train" >/dev/null; then echo "a run is going: scripts/campaign.sh stop first" >&2; exit 1; fi
}

launch() {  # RUN ARGS...: start `mipnet train ARGS` on the engine snapshot, logging to RUN
  local run=$1; shift
  mkdir -p "$run" "$ENGINE"
  rm -rf "$ENGINE/mipnet.new" && cp -a python/mipnet "$ENGINE/mipnet.new"
  rm -rf "$ENGINE/mipnet" && mv "$ENGINE/mipnet.new" "$ENGINE/mipnet"
  echo "$(date -u +%FT%TZ) $PY -m mipnet train $*" >> "$run/commands.txt"
  PYTHONPATH=$ENGINE MIPNET_NUM_THREADS=2 nohup nice -n 19 "$PY" -m mipnet train "$@" >> "$run/stdout.log" 2>&1 &
  echo "started $(basename "$run") (pid $!): $*"
}

case "${1:-}" in
  cycle)
    require_idle
    stamp=$(date -u +%Y%m%d-%H%M)
    run=$ROOT/train/cycle-$stamp
    mkdir -p "$run" && cp "${INIT:-$SHIPPED}" "$run/init.safetensors"
    # each cycle's data seed is its start time, so it draws pairs no earlier cycle saw (unless SEED is given)
    launch "$run" --config "${3:-campaign-s12}" --steps "${2:-1000}" --init "$run/init.safetensors" \
      --seed "${SEED:-$(( 10#${stamp//-/} % 2147483647 ))}" --out "$run"
    ;;
  resume)
    require_idle
    launch "$ROOT/train/${2:?run name}" --resume "$ROOT/train/$2"
    ;;
  stop)
    # the run's main process only (the oldest match): its loader workers end when it tells them
    pid=$(pgrep -o -f "mipnet train" || true)
    if [ -n "$pid" ]; then kill -TERM "$pid" && echo "SIGTERM sent to $pid; waiting for the checkpoint"; else echo "no run"; fi
    while pgrep -f "mipnet train" >/dev/null; do sleep 2; done
    ;;
  status)
    for run in "$ROOT"/train/*/; do
      echo "== $run"; tail -n 2 "$run/log.jsonl" 2>/dev/null | cut -c1-300
      grep '"val"' "$run/log.jsonl" 2>/dev/null | tail -n 1 | cut -c1-600
    done
    ;;
  *) sed -n 2,14p "$0"; exit 2 ;;
esac
