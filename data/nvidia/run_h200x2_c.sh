#!/usr/bin/env bash
# Third call on the two-H200 machine: the light calibration runs showed 0.5-1.4 ms
# between a task's end and its dependant's start across devices/host. Measure fence wake-up
# latency with and without busy Python threads, then every calibration and validation run again
# with a 0.2 ms GIL switch interval (MGPUSIM_SWITCH_INTERVAL_S). From the project root:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_h200x2_c.sh $OUT/h200x2_c
set -u
out=${1:?output folder}; t0=$SECONDS; py=${PYTHON:-python3}; mkdir -p "$out"
timeout 60 $py data/nvidia/host_latency.py "$out/host_latency.csv" 2>&1 | tee "$out/host_latency.log"
export MGPUSIM_SWITCH_INTERVAL_S=0.0002
timeout ${CAL_BUDGET:-100} $py -m mgpusim.cli study measure experiments/h200/study.toml --devices 0,1 --out "$out/calibration_si" 2>&1 | tee "$out/calibration_si.log"
timeout ${RUN_BUDGET:-180} $py -m mgpusim.cli study measure experiments/h200/study.toml --held-out --devices 0,1 --out "$out/runs_si" 2>&1 | tee "$out/runs_si.log"
echo "total $((SECONDS - t0))s"
