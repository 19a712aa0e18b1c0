#!/usr/bin/env bash
# Does training with (3, 3) or with (4, 4) iterations serve (6, 6) at test time better, for the same CPU time?
# (docs/training.md, "(3, 3) or (4, 4) in training")
#
#   scripts/iters_compare.sh INIT [STEPS_4x4] [STEPS_3x3]
#
# Two stage-7 runs (scripts/campaign.sh: 256x512 crops, batch 2, the water-heavy mix with the row veil) from the
# same weights INIT, with the same seed (so the same pairs in the same order), each on one thread at the same
# time at nice 19, so both see the same machine. The (3, 3) run gets as many more steps as its steps are cheaper
# (default 200 and 240: a (3, 3) step costs about 0.83 of a (4, 4) one, from the profile of
# `python -m mipnet.bench model --sizes --train 256x512x2:4,4 --engines mipnet --profile`). Each one-cycle
# anneals to zero and both are validated at 384x512 with (6, 6) at their end; then compare them with
# `python scripts/validate_weights.py RUN/model.safetensors --size 384 512 --pairs 16 --no-untrained`.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${MIPNET_CAMPAIGN_ROOT:-$HOME/.cache/mipnet}
PY=${PYTHON:-python}
init=${1:?weights to start from}
steps44=${2:-200}
steps33=${3:-240}
stamp=$(date -u +%Y%m%d-%H%M)
# the package as it is now, so that rebuilding or a campaign start never changes the code under these runs
engine=$ROOT/engine-iters-$stamp
mkdir -p "$engine" && cp -a python/mipnet "$engine/"
seed=$(( 10#${stamp//[!0-9]/} % 2147483647 ))
# stage 7's arguments; the --iters and --val-every given after them win
common="--preset cpu $(scripts/campaign.sh args s7) --seed $seed"
for spec in "4 4 $steps44" "3 3 $steps33"; do
  read -r n16 n4 steps <<<"$spec"
  run=$ROOT/train/iters-$stamp-${n16}x${n4}
  mkdir -p "$run"
  cp "$init" "$run/init.safetensors"
  args="$common --iters $n16 $n4 --steps $steps --val-every $steps --init $run/init.safetensors --out $run"
  echo "$(date -u +%FT%TZ) MIPNET_NUM_THREADS=1 $PY -m mipnet train $args" >> "$run/commands.txt"
  # shellcheck disable=SC2086
  PYTHONPATH=$engine MIPNET_NUM_THREADS=1 nohup nice -n 19 "$PY" -m mipnet train $args >> "$run/stdout.log" 2>&1 &
  echo "started $run (pid $!)"
done
