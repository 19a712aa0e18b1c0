#!/usr/bin/env bash
# The CPU training campaign of the shipped weights (docs/training.md), one stage at a time, in the
# background at the lowest priority, resumed across sessions.
#
#   scripts/campaign.sh start STAGE   # start STAGE (or resume it if its run folder has a checkpoint)
#   scripts/campaign.sh cycle [STEPS] [s1|...|s13]
#                                     # one session's cycle: a new one-cycle run of STEPS (default 1000)
#                                     # with stage 1's (default) to 13's settings, from the shipped
#                                     # weights (or INIT=weights.safetensors), in train/cycle-DATE
#   scripts/campaign.sh stop          # SIGTERM: the run checkpoints after its current step and exits
#   scripts/campaign.sh status        # last log lines and validation of the running stage
#   scripts/campaign.sh args KIND     # print the training arguments of cycle kind KIND (s1 to s13)
#
# The run uses a snapshot of the package (python/ and the built core) copied to ENGINE, so rebuilding
# or editing the working tree never changes the code under a running process; `start` refreshes the
# snapshot, so a stop + start switches the run to the current engine (checkpoints are engine-independent).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${MIPNET_CAMPAIGN_ROOT:-$HOME/.cache/mipnet}
ENGINE=$ROOT/engine
PY=${PYTHON:-python}
SHIPPED=python/mipnet/assets/mipnet_pretrained.safetensors

# stage -> the arguments of its first start (a resumed stage keeps its own settings)
stage_args() {
  case "$1" in
    # 1: small crops and few iterations while matching emerges
    # (a machine that lost the run folder restarts it from the shipped weights, which come from this stage)
    s1-128x256) echo "--preset cpu --steps 20000 --crop 128 256 --batch-size 4 --iters 3 3 --lr 4e-4${RESTART_INIT:+ --init $RESTART_INIT}" ;;
    # 2: larger crops, a wider disparity range, inference-like iterations, from stage 1's best weights
    s2-192x384) echo "--preset cpu --steps 10000 --crop 192 384 --batch-size 2 --iters 4 4 --lr 2e-4 --init $ROOT/train/s1-128x256/best.safetensors" ;;
    # a session's cycle: a short one-cycle from the shipped weights that anneals to zero within one
    # session, so a session ends on annealed weights even if its machine is not kept; its data seed is
    # its start time, so each cycle draws pairs no earlier cycle saw
    cycle-*) echo "--preset cpu --steps ${CYCLE_STEPS:-1000} $(cycle_args "${CYCLE_KIND:-s1}") --init $RESTART_INIT --seed $(( 10#${1//[!0-9]/} % 2147483647 ))" ;;
    *) echo "unknown stage $1" >&2; exit 2 ;;
  esac
}

# a cycle's crops, iterations and data: stage 1's, stage 2's larger crops with inference-like
# iterations and more water, or stage 3's still more water (the under-water sets lose most at large images: docs/training.md)
cycle_args() {
  # the crops of stages 2-3, and of stages 4-5 (as wide as the evaluation's 512 columns, validated at its 384x512)
  local mid="--crop 192 384 --batch-size 2 --iters 4 4 --lr 2e-4"
  local wide="--crop 256 512 --batch-size 2 --iters 4 4 --lr 2e-4 --val-size 384 512 --val-every 200"
  # more than half of the pairs in air, or seven in ten under water
  local air_heavy="--data scenes:0.45 scenes-underwater:0.35 synthetic:0.1 synthetic-underwater:0.1"
  local water_heavy="--data scenes:0.25 scenes-underwater:0.5 synthetic:0.05 synthetic-underwater:0.2"
  # between the two: 57% of the pairs under water
  local water_mid="--data scenes:0.35 scenes-underwater:0.42 synthetic:0.08 synthetic-underwater:0.15"
  case "$1" in
    s1) echo "--crop 128 256 --batch-size 4 --iters 3 3 --lr 3e-4" ;;
    s2) echo "$mid $air_heavy" ;;
    # 3: fine-tuning on degraded pairs last: stage 2's crops with seven pairs in ten under water
    s3) echo "$mid $water_heavy" ;;
    # 4: stage 3's water with wide crops (the under-water pairs lose most at 384x512, where a hazy far plane
    # spans more of the view than any 384-wide crop)
    s4) echo "$wide $water_heavy" ;;
    # 5: wide crops with stage 2's mix: stage 4's water-heavy mix taught "pale, weakly textured = far" (hazy far
    # planes), which put a real photograph's near floor far away
    s5) echo "$wide $air_heavy" ;;
    # 6: stage 5 with the row veil on a third of the pairs: both earlier weights lose most of their accuracy where
    # a pale veil fades near rows (the scenes_veiled validation set), and a veil that ignores depth makes low
    # contrast a reason to match harder instead of a sign of distance
    s6) echo "$wide $air_heavy --veil 0.35" ;;
    # 7: stage 4's water-heavy mix with stage 6's veil: stage 4 brought the under-water sets closest to their
    # targets and lost the real pairs to "pale means far", the prior the veil now argues against
    s7) echo "$wide $water_heavy --veil 0.35" ;;
    # 8: stage 6 with a scale augmentation that shrinks more than it enlarges: with RAFT-Stereo's range the generated
    # pairs (drawn 1.25x the crop, disparities growing with the drawn width) reached the crops 1.35x enlarged on
    # average, so far planes below 8 px, where low light fails, were almost absent from the planar scenes
    s8) echo "$wide $air_heavy --veil 0.35 --spatial-scale -0.3 0.1" ;;
    # 9: stage 8 with dim light and sensor noise on a third of the crops: low-light pairs rendered without sensor
    # noise lose a third of their EPE and half of their bad-3 (docs/training.md), so the noise, not the dark, is
    # what the network fails to match through; drawn on every scene at every depth, it stops meaning "far"
    s9) echo "$wide $air_heavy --veil 0.35 --spatial-scale -0.3 0.1 --noise 0.3" ;;
    # 10: stage 9's noise on the pairs in air only: stage 9 made air, the scenes and the real pairs better and both
    # under-water sets worse, having laid random dim spots over the water's own dive light (where dark is far); the
    # under-water generator already draws a sensor's noise under that light
    s10) echo "$wide $air_heavy --veil 0.35 --spatial-scale -0.3 0.1 --noise 0.3 --noise-sources air" ;;
    # 11: stage 8 with the water share between stages 6 and 7: every stage-8 cycle gained in air and on the scenes
    # and lost under water, stage 7's seven pairs in ten lost the veiled scenes and the real pairs
    s11) echo "$wide $water_mid --veil 0.35 --spatial-scale -0.3 0.1" ;;
    # 12: stage 11 at half its peak LR: its third cycle, from the mean of its first two ends and their starts, gained
    # nothing at 2e-4 (its end 0.05-0.6 px worse than its start, the mean of the two no better): smaller steps from
    # the averaged weights, which an LR of 2e-4 throws out of their basin for most of a short cycle
    s12) echo "${wide/--lr 2e-4/--lr 1e-4} $water_mid --veil 0.35 --spatial-scale -0.3 0.1" ;;
    # 13: stage 12 with seven pairs in ten under water (stage 7's mix, with the veil and the scale augmentation that
    # stage 7 lacked at first): both stage-12 cycles gained in air and on the scenes and lost in turbid water
    s13) echo "${wide/--lr 2e-4/--lr 1e-4} $water_heavy --veil 0.35 --spatial-scale -0.3 0.1" ;;
    *) echo "unknown cycle kind $1 (s1 to s13)" >&2; exit 2 ;;
  esac
}

case "${1:-}" in
  start|cycle)
    if [ "$1" = cycle ]; then
      stage=cycle-$(date -u +%Y%m%d-%H%M) CYCLE_STEPS=${2:-1000} CYCLE_KIND=${3:-s1}
      cycle_args "$CYCLE_KIND" >/dev/null
    else
      stage=${2:?stage name}
    fi
    run=$ROOT/train/$stage
    mkdir -p "$ROOT/train" "$ENGINE"
    if pgrep -f "mipnet train" >/dev/null; then echo "a run is going: scripts/campaign.sh stop first" >&2; exit 1; fi
    rm -rf "$ENGINE/mipnet.new" && cp -a python/mipnet "$ENGINE/mipnet.new"
    rm -rf "$ENGINE/mipnet" && mv "$ENGINE/mipnet.new" "$ENGINE/mipnet"
    if [ -d "$run/checkpoint" ] && ls "$run"/checkpoint/ckpt-*.safetensors >/dev/null 2>&1; then
      args="--resume $run"
    else
      if { [ "$stage" = s1-128x256 ] || [ "${stage#cycle-}" != "$stage" ]; } && [ -f "$SHIPPED" ]; then
        mkdir -p "$run" && cp "${INIT:-$SHIPPED}" "$run/restart-init.safetensors" && RESTART_INIT=$run/restart-init.safetensors
      fi
      args="$(stage_args "$stage") --out $run"
    fi
    mkdir -p "$run"
    echo "$(date -u +%FT%TZ) $PY -m mipnet train $args" >> "$run/commands.txt"
    # shellcheck disable=SC2086
    PYTHONPATH=$ENGINE MIPNET_NUM_THREADS=2 nohup nice -n 19 "$PY" -m mipnet train $args >> "$run/stdout.log" 2>&1 &
    echo "started $stage (pid $!): $args"
    ;;
  stop)
    # the run's main process only (the oldest match): its loader workers end when it tells them
    pid=$(pgrep -o -f "mipnet train" || true)
    if [ -n "$pid" ]; then kill -TERM "$pid" && echo "SIGTERM sent to $pid; waiting for the checkpoint"; else echo "no run"; fi
    while pgrep -f "mipnet train" >/dev/null; do sleep 2; done
    ;;
  args)
    cycle_args "${2:?cycle kind}"
    ;;
  status)
    for run in "$ROOT"/train/*/; do
      echo "== $run"; tail -n 2 "$run/log.jsonl" 2>/dev/null | cut -c1-300
      grep '"val"' "$run/log.jsonl" 2>/dev/null | tail -n 1 | cut -c1-600
    done
    ;;
  *) sed -n 2,14p "$0"; exit 2 ;;
esac
