#!/usr/bin/env bash
# The four newer schedules (AFR ideal and temporal, frame pipelining, XR, particle offload) on
# one NVIDIA GPU: each run once with one simulated GPU and once with several simulated GPUs on
# the same physical GPU (one VkDevice each, 4 untimed frames first in both, since the temporal
# pass accumulates over every frame), and the final displayed images compared; then the
# filter and particle passes measured on that GPU. From the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_schedules_1gpu.sh $OUT/sched1
set -u
out=${1:?output folder}; py=${PYTHON:-python3}; mkdir -p "$out"
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1; head -5 "$out/devices.txt"
run() {  # name experiment extra --set items...
  local name=$1 exp=$2; shift 2
  local sets=(); for s in "$@"; do sets+=(--set "$s"); done
  timeout 120 $py -m mgpusim.cli run "experiments/lavapipe/$exp.toml" --gpus-per-device 8 --prewarm 4 "${sets[@]}" \
    --set schedule.frames=30 --out "$out/$name" > "$out/$name.log" 2>&1
  echo "$name rc=$? $(grep -o 'frame time [0-9.]* ms' "$out/$name.log" | head -1)"
}
run afr_1 afr schedule.gpus=1
run afr_2 afr
run afrt_1 afr_temporal schedule.gpus=1
run afrt_2 afr_temporal
run pipe_1 pipelining schedule.gpus=1
run pipe_2 pipelining
run pipe_2_chunks4 pipelining schedule.chunks=4
run xr_sim xr schedule.gpus=1 schedule.mode=simulated schedule.views=2
run xr_2 xr
run xr_2_strong xr schedule.scaling=strong
run part_1_wait particles schedule.gpus=1 schedule.particle_gpu=0 schedule.policy=wait
run part_2_wait particles schedule.policy=wait
run part_2_new_wait particles
$py - "$out" <<'PY' | tee "$out/pictures.txt"
import sys
from pathlib import Path
import matplotlib.image as mpimg
import numpy as np
out = Path(sys.argv[1])
for one, many in [("afr_1", "afr_2"), ("afrt_1", "afrt_2"), ("pipe_1", "pipe_2"), ("pipe_1", "pipe_2_chunks4"),
                  ("xr_sim", "xr_2"), ("xr_sim", "xr_2_strong"), ("part_1_wait", "part_2_wait")]:
    a, b = out / one / "image.png", out / many / "image.png"
    if not (a.is_file() and b.is_file()):
        print(f"{one} vs {many}: missing image"); continue
    same = np.array_equal(mpimg.imread(a), mpimg.imread(b))
    print(f"{one} vs {many}: {'identical' if same else 'DIFFERENT'}")
PY
R="--reps 5 --warmup 3 --device 0"
timeout 60 $py -m mgpusim.cli measure --quiet --pass filter $R --sweep width=1920,3840 --sweep height=1080,2160 --sweep iterations=100,500 --sweep inputs=1,3 --out "$out/filter.csv"; echo "filter rc=$?"
timeout 60 $py -m mgpusim.cli measure --quiet --pass particle_update $R --sweep particles=65536,262144,1048576 --out "$out/particle_update.csv"; echo "particle_update rc=$?"
