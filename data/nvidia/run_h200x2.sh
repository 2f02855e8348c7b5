#!/usr/bin/env bash
# One call on the two-H200 machine: the five-step validation runs for real on both GPUs
# (one VkDevice each, the held-out half of experiments/h200/study.toml), then the pass library on one H200 and both
# GPUs copying at once. From the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_h200x2.sh $OUT/h200x2
set -u
out=${1:?output folder}; budget=${BUDGET:-480}; t0=$SECONDS
py=${PYTHON:-python3}; mkdir -p "$out"
left() { echo $(( budget - (SECONDS - t0) )); }
go() {
  local name=$1 to=$2; shift 2; local l; l=$(left)
  if (( l < 15 )); then echo "SKIP (time): $name" | tee -a "$out/status.txt"; return; fi
  (( to > l - 5 )) && to=$(( l - 5 ))
  local s=$SECONDS; timeout "$to" "$@" > "$out/$name.log" 2>&1; local rc=$?
  echo "$name rc=$rc $((SECONDS - s))s" | tee -a "$out/status.txt"; tail -2 "$out/$name.log"
}
m() { local name=$1 to=$2; shift 2; go "$name" "$to" $py -m mgpusim.cli measure --quiet "$@" --out "$out/$name.csv"; }
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1; head -30 "$out/devices.txt"
nvidia-smi > "$out/nvidia-smi.txt" 2>&1; nvidia-smi topo -m >> "$out/nvidia-smi.txt" 2>&1
# 1. the validation runs on GPUs 0 and 1
timeout ${RUN_BUDGET:-240} $py -m mgpusim.cli study measure experiments/h200/study.toml --held-out --devices 0,1 --out "$out/runs" 2>&1 | tee "$out/runs.log"
# 2. one H200 (device 0), then both at once
R="--reps 5 --warmup 3 --device 0"
m copy_d2h 30 --pass copy_d2h $R --sweep bytes=1MiB,16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m copy_h2d 30 --pass copy_h2d $R --sweep bytes=1MiB,16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m copy_d2d 30 --pass copy_d2d $R --sweep bytes=1MiB,16MiB,256MiB,1GiB --sweep queue=graphics,transfer
m host_copy 40 --pass host_copy $R --sweep bytes=16MiB,128MiB,512MiB --sweep threads=1,2,4,8,16,32
m composite_sort_first 30 --pass composite_sort_first $R --sweep width=1920,3840,7680 --sweep height=1080,2160,4320 --sweep inputs=2
m composite_sort_last 30 --pass composite_sort_last $R --sweep width=1920,3840,7680 --sweep height=1080,2160,4320 --sweep inputs=2
m fragment_loop 60 --pass fragment_loop $R --sweep width=1920,3840,7680 --sweep height=1080,4320 --sweep iterations=100,1000,4000
m mesh 60 --pass mesh $R --sweep width=1920,7680 --sweep height=2160 --sweep triangles=1000000,10000000,30000000
R2="--reps 5 --warmup 3 --gpus 2"
m copy_d2h_2gpus 30 --pass copy_d2h $R2 --sweep bytes=16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m copy_h2d_2gpus 30 --pass copy_h2d $R2 --sweep bytes=16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m fragment_loop_2gpus 30 --pass fragment_loop $R2 --sweep width=3840 --sweep height=2160 --sweep iterations=1000,4000
echo "total $((SECONDS - t0))s" | tee -a "$out/status.txt"
