#!/usr/bin/env bash
# Second call on the two-H200 machine, after the first showed 32 Python host-copy
# threads contending: the profile now splits host copies over 8 threads. Calibration runs
# (the calibration half of experiments/h200/study.toml), the held-out validation runs (the held-out half) again, and
# host copies around the sizes the schedules use. From the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_h200x2_b.sh $OUT/h200x2_b
set -u
out=${1:?output folder}; t0=$SECONDS; py=${PYTHON:-python3}; mkdir -p "$out"
nvidia-smi > "$out/nvidia-smi.txt" 2>&1
timeout ${CAL_BUDGET:-110} $py -m mgpusim.cli study measure experiments/h200/study.toml --devices 0,1 --out "$out/calibration" 2>&1 | tee "$out/calibration.log"
timeout ${RUN_BUDGET:-200} $py -m mgpusim.cli study measure experiments/h200/study.toml --held-out --devices 0,1 --out "$out/runs" 2>&1 | tee "$out/runs.log"
timeout 60 $py -m mgpusim.cli measure --quiet --pass host_copy --reps 7 --warmup 3 --sweep bytes=4MiB,8MiB,16MiB,32MiB,64MiB,128MiB,192MiB --sweep threads=4,8,16 --out "$out/host_copy.csv" > "$out/host_copy.log" 2>&1; echo "host_copy rc=$?"
echo "total $((SECONDS - t0))s"
