#!/usr/bin/env bash
# The data ablation of the real-photograph issue: the three arms of python/mipnet/training/recipes/ablation-*.toml
# (procedural only, photos only, both), one after the other, each from the same weights for the same steps with
# the same seed, in the background at the lowest priority; each run validates once at its end (log.jsonl "val"),
# on the held-out generated sets including the held-out photographs.
#
#   scripts/ablation.sh [STEPS] [INIT]     # default 200 steps from the shipped weights
#   scripts/ablation.sh table              # the validation table of the three runs (EPE / bad-3)
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${MIPNET_CAMPAIGN_ROOT:-$HOME/.cache/mipnet}/ablation
PY=${PYTHON:-python}
if [ "${1:-}" = table ]; then
  exec "$PY" - "$ROOT" <<'PYEOF'
import json, sys
from pathlib import Path
for run in sorted(Path(sys.argv[1]).glob("*/log.jsonl")):
    rows = [json.loads(line) for line in run.read_text().splitlines() if '"val"' in line]
    if rows:
        val = rows[-1]["val"]
        cells = "  ".join(f"{k} {v['epe']:.3f}/{v['bad3']:.1f}%" for k, v in val.items())
        print(f"{run.parent.name:12} step {rows[-1]['step']}: {cells}")
PYEOF
fi
steps=${1:-200}
init=${2:-python/mipnet/assets/mipnet_pretrained.safetensors}
mkdir -p "$ROOT/engine"
cp "$init" "$ROOT/init.safetensors"
# a snapshot of the package (python/ and the built core): editing the tree never changes the code under the runs
rm -rf "$ROOT/engine/mipnet" && cp -a python/mipnet "$ROOT/engine/mipnet"
for arm in procedural photos both; do
  echo "$PY -m mipnet train --config ablation-$arm --init $ROOT/init.safetensors --steps $steps --seed 41 --val-every $steps --val-pairs 16 --out $ROOT/$arm"
done > "$ROOT/commands.txt"
PYTHONPATH=$ROOT/engine MIPNET_NUM_THREADS=2 nohup nice -n 19 bash "$ROOT/commands.txt" > "$ROOT/stdout.log" 2>&1 &
echo "started the three arms (pid $!); scripts/ablation.sh table when they are done"
