#!/bin/bash
# The series of this folder's core_use.csv (see README.md). Run from the repository root with
# eevdf_slice.patch applied (it adds the XSLICE/XSCOPE levels; without them it is the shipped code).
set -euo pipefail
D=data/lavapipe/afr4_core_use_2026-11-25
OUT=${OUT:-/tmp/afr4_core_use}
mkdir -p "$OUT"
run() {  # run LABEL GPUS WIDTH HEIGHT FRAMES [ENV...]
  local label=$1 g=$2 w=$3 h=$4 f=$5; shift 5
  env "$@" .venv/bin/python experiments/lavapipe/core_use.py --label "$label" --csv $D/core_use.csv -- \
    .venv/bin/mgpusim run experiments/lavapipe/afr.toml --set schedule.gpus=$g --set scene.width=$w \
    --set scene.height=$h --set schedule.frames=$f --set schedule.warmup_frames=20 --lp-threads 8 \
    --out "$OUT/$label.$RANDOM"
}
spinners() {  # two SCHED_IDLE busy loops, one per core: they only take time nobody else wants
  for c in 0 1; do
    python3 -c "import os; os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0)); os.sched_setaffinity(0, {$c})
while True: pass" & done
}
for round in 1 2; do
  run "afr4_128x96 normal" 4 128 96 1500 MGPUSIM_HOST_PRIORITY=normal
  run "afr4_128x96 realtime" 4 128 96 1500 MGPUSIM_HOST_PRIORITY=realtime
  run "afr4_128x96 slice_all" 4 128 96 1500 MGPUSIM_HOST_PRIORITY=realtime XSLICE=100000
  run "afr4_128x96 slice_queue" 4 128 96 1500 MGPUSIM_HOST_PRIORITY=realtime XSLICE=100000 XSCOPE=queue
  spinners; run "afr4_128x96 idle_spinners" 4 128 96 1500 MGPUSIM_HOST_PRIORITY=normal; kill $(jobs -p)
done
for g in 1 2 3 4; do run "afr${g}_128x96 normal" $g 128 96 2000 MGPUSIM_HOST_PRIORITY=normal; done
for g in 1 2 4; do run "afr${g}_256x192 normal" $g 256 192 600 MGPUSIM_HOST_PRIORITY=normal; done
