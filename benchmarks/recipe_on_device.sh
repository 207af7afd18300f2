#!/bin/bash
# A recipe's data built and its three networks trained in one lease of a GPU machine, detached.
#
#   bash benchmarks/recipe_on_device.sh RECIPE TRAIN_SECONDS [GPU_WORKERS] [CPU_WORKERS]
#
# Expects what the lease's first calls carried and unpacked (benchmarks/device_factory.py; the calls
# are listed in docs/journal/2026-11-29-factory-on-device.md):
#   /tmp/fenv           the relocated Python 3.11 with bpy (`device_factory.py unpack`)
#   /tmp/cudacache      Cycles' OptiX kernels JIT-compiled for the H200 (else the first render waits ~8 min)
#   /tmp/init/*.pt      the stored weights the recipe's networks start from (their pinned SHA-256 is checked)
# Writes /tmp/data/RECIPE (the data), /tmp/runs/<task> (each run), /tmp/export (int8 weights, logs,
# evaluations on the hold-out parts) and /tmp/lease.log; /tmp/lease.done when it ends.
# The build's simulations run on the CPU workers; its renders on GPU_WORKERS Cycles processes on the
# GPU (default 6) and the CPU workers (default 10) once they are free.  The three trainings then share
# the GPU, each for TRAIN_SECONDS (its schedule fitted to them) with 5 data workers.
set -u
RECIPE=$1; TRAIN_S=$2; GPU_WORKERS=${3:-6}; CPU_WORKERS=${4:-10}
DATA=/tmp/data/$RECIPE; RUNS=/tmp/runs; EXPORT=/tmp/export
mkdir -p "$DATA" "$RUNS" "$EXPORT"
exec > /tmp/lease.log 2>&1
stamp() { echo "== $(date +%T) $*"; }

stamp build
(
    . /tmp/fenv/env.sh
    export CUDA_CACHE_PATH=/tmp/cudacache CUDA_CACHE_MAXSIZE=4294967296
    python3.11 benchmarks/device_recipe.py "$RECIPE" --out "$DATA" --workers "$CPU_WORKERS" --gpu-workers "$GPU_WORKERS"
) || { stamp "build failed"; touch /tmp/lease.done; exit 1; }

stamp train
declare -A INIT=([localizer]=localizer.pt [recognizer]=reader.pt [crosspoints]=crosspoints.pt)
for task in localizer recognizer crosspoints; do
    PYTHONUNBUFFERED=1 python3 -m networks.train "$task" --recipe "$RECIPE" --data "$DATA" \
        --init "/tmp/init/${INIT[$task]}" --out "$RUNS/$task" --workers 5 \
        --time-limit "$TRAIN_S" --fit-time-limit --no-progress > "$RUNS/$task.log" 2>&1 &
done
wait
for task in localizer recognizer crosspoints; do stamp "$task"; tail -2 "$RUNS/$task.log"; done

stamp export
for task in localizer recognizer crosspoints; do
    [ -f "$RUNS/$task/last.pt" ] || continue
    python3 -m networks.checkpoint slim --int8 "$RUNS/$task/last.pt" "$EXPORT/${INIT[$task]}"
    cp "$RUNS/$task/log.jsonl" "$EXPORT/$task.log.jsonl"; cp "$RUNS/$task/recipe.json" "$EXPORT/$task.recipe.json"
    extra=(); [ "$task" = recognizer ] && extra=(--garment-ids)   # fully visible top-1 among the garment's IDs
    for part in "$DATA"/holdout/*/; do
        python3 -m networks.evaluate "$task" "${extra[@]}" --checkpoint "$RUNS/$task/last.pt" --data "$part" --split all \
            --json "$EXPORT/eval_${task}_$(basename "$part").json" --no-progress > /dev/null 2>&1
    done
done
cp "$DATA/factory_run.json" "$EXPORT/"
stamp done
touch /tmp/lease.done
