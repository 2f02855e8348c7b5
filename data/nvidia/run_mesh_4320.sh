#!/usr/bin/env bash
# The mesh at full 4320-row frames (the 2nd-round tables stopped at 2160 rows, and the 8K 1-GPU
# validation run showed the pixel term extrapolated), and with RUNS=1 the 1-GPU validation
# configurations (the held-out half of experiments/h200/study.toml *_1gpu) on device 0. From the project root:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_mesh_4320.sh $OUT/x
set -u
out=${1:?output folder}; t0=$SECONDS; py=${PYTHON:-python3}; mkdir -p "$out"
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1
timeout 120 $py -m mgpusim.cli measure --quiet --reps 5 --warmup 3 --device 0 --pass mesh --sweep width=3840,7680 --sweep height=4320 --sweep triangles=1000000,10000000,30000000 --out "$out/mesh_4320.csv" > "$out/mesh_4320.log" 2>&1; echo "mesh_4320 rc=$? $((SECONDS - t0))s"
if [ "${RUNS:-0}" = 1 ]; then
  export MGPUSIM_SWITCH_INTERVAL_S=0.0002
  timeout 150 $py -m mgpusim.cli study measure experiments/h200/study.toml --held-out --only _1gpu --devices 0 --out "$out/runs_1gpu" 2>&1 | tee "$out/runs_1gpu.log"
fi
echo "total $((SECONDS - t0))s"
