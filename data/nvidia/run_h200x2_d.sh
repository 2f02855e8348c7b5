#!/usr/bin/env bash
# Fourth call on the two-H200 machine: the 1-GPU validation configurations, every
# validation run repeated (run-to-run spread), and the particle passes on an H200. All runs with
# the 0.2 ms GIL switch interval, as runs_si/. From the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_h200x2_d.sh $OUT/h200x2_d
set -u
out=${1:?output folder}; t0=$SECONDS; py=${PYTHON:-python3}; mkdir -p "$out"
export MGPUSIM_SWITCH_INTERVAL_S=0.0002
# 1. the new configurations (1 GPU) and a repeat of every 2-GPU one
timeout ${RUN_BUDGET:-200} $py -m mgpusim.cli study measure experiments/h200/study.toml --held-out --devices 0,1 --out "$out/runs_si_rep" 2>&1 | tee "$out/runs_si_rep.log"
# 2. particles on one H200
R="--quiet --reps 5 --warmup 3 --device 0"
timeout 40 $py -m mgpusim.cli measure $R --pass particle_update --sweep particles=65536,1048576,4194304,16777216 --out "$out/particle_update.csv" > "$out/particle_update.log" 2>&1; echo "particle_update rc=$?"
timeout 60 $py -m mgpusim.cli measure $R --pass particle_render --sweep width=1920,3840 --sweep height=2160 --sweep particles=65536,262144,1048576 --out "$out/particle_render.csv" > "$out/particle_render.log" 2>&1; echo "particle_render rc=$?"
echo "total $((SECONDS - t0))s"
