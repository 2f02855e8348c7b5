#!/usr/bin/env bash
# One H100 call: smoke-test the Vulkan runner on NVIDIA, then measure the pass library
# at GPU-dominant sizes. Run from the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/run_h100.sh $OUT/h100
# Stops itself before BUDGET seconds (default 500), keeping what it has.
set -u
out=${1:?output folder}; budget=${BUDGET:-500}; t0=$SECONDS
py=${PYTHON:-python3}; mkdir -p "$out"
left() { echo $(( budget - (SECONDS - t0) )); }
go() { # go NAME TIMEOUT CMD...: run if time is left, log duration/status
  local name=$1 to=$2; shift 2; local l; l=$(left)
  if (( l < 15 )); then echo "SKIP (time): $name" | tee -a "$out/status.txt"; return; fi
  (( to > l - 5 )) && to=$(( l - 5 ))
  local s=$SECONDS; timeout "$to" "$@" > "$out/$name.log" 2>&1; local rc=$?
  echo "$name rc=$rc $((SECONDS - s))s" | tee -a "$out/status.txt"; tail -3 "$out/$name.log"
}
m() { local name=$1 to=$2; shift 2; go "$name" "$to" $py -m mgpusim.cli measure --quiet "$@" --out "$out/$name.csv"; }
r() { local name=$1 to=$2; shift 2; go "run_$name" "$to" $py -m mgpusim.cli run "$@" --out "$out/run_$name"; }
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1; head -40 "$out/devices.txt"; nvidia-smi > "$out/nvidia-smi.txt" 2>&1
# 1. smoke: the five-step runner, 2 simulated GPUs on the one H100
S="--gpus-per-device 2 --set schedule.frames=16 --set schedule.warmup_frames=4"
r sf_1080p 60 experiments/h200/sort_first.toml $S --set scene.width=1920 --set scene.height=1080
r sl_1080p 60 experiments/h200/sort_last.toml $S --set scene.width=1920 --set scene.height=1080 --set 'scene.passes=[{name="mesh",kind="mesh",triangles=1000000}]'
r sf_4k_nohost 60 experiments/h200/sort_first.toml $S --set schedule.host_copy=false
r sl_4k_nohost 60 experiments/h200/sort_last.toml $S --set schedule.host_copy=false --set 'scene.passes=[{name="mesh",kind="mesh",triangles=1000000}]'
# 2. measure
R="--reps 5 --warmup 3"
m copy_d2h 40 --pass copy_d2h $R --sweep bytes=1MiB,16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m copy_h2d 40 --pass copy_h2d $R --sweep bytes=1MiB,16MiB,128MiB,512MiB --sweep queue=graphics,transfer
m copy_d2d 40 --pass copy_d2d $R --sweep bytes=1MiB,16MiB,256MiB,1GiB --sweep queue=graphics,transfer
m fragment_loop 90 --pass fragment_loop $R --sweep width=1920,3840,7680 --sweep height=1080,2160,4320 --sweep iterations=100,1000,10000,50000
m composite_sort_first 40 --pass composite_sort_first $R --sweep width=1920,3840,7680 --sweep height=1080,2160,4320 --sweep inputs=2,4
m composite_sort_last 40 --pass composite_sort_last $R --sweep width=1920,3840,7680 --sweep height=1080,2160,4320 --sweep inputs=2,4
m host_copy 60 --pass host_copy $R --sweep bytes=16MiB,128MiB,512MiB --sweep threads=1,2,4,8,16
m mesh 120 --pass mesh $R --sweep width=1920,3840,7680 --sweep height=2160 --sweep triangles=1000000,10000000,30000000
m particle_update 30 --pass particle_update $R --sweep particles=65536,1048576,16777216
m particle_render 30 --pass particle_render $R --sweep width=3840 --sweep height=2160 --sweep particles=65536,1048576,16777216
echo "total $((SECONDS - t0))s" | tee -a "$out/status.txt"
