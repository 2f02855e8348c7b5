#!/usr/bin/env bash
# Bring your own frame on 4x NVIDIA H100: capture -> import -> advise -> run the advised options.
# On the device machine, from the project root (carrying .gl, .whl and .spvcache filled here):
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; export MGPUSIM_CACHE=$PWD/.spvcache
#   bash tools/advise_validation/h100_x4.sh $OUT/advise
# Five frames (tools/advise_validation/h100_x4.py) in one process: real GPUs share one
# VkInstance per process (mgpusim/real/vulkan/machine.py), so the driver's limit of ~30
# instances per process is never reached. No frame starts after DEADLINE_S seconds (default
# 230); the process is killed after TIMEOUT_S (default 420). A failed or killed process is
# started once more and resumes: finished frames (OUT/frames/*.csv) are skipped. Every real run
# is appended to OUT/runs.csv as it ends; OUT/results.csv and OUT/summary.txt gather the
# finished frames; OUT/log.txt has the progress, OUT/stdout.txt everything printed. About
# 3-4 minutes.
set -u
out=${1:?output folder}; shift  # the rest goes to the Python script (--dry-run: offline check)
py=${PYTHON:-python3}
deadline=${DEADLINE_S:-230}
limit=${TIMEOUT_S:-420}
script=tools/advise_validation/h100_x4.py
mkdir -p "$out"
# one profile per card model: the 4x H200 machine gets its own
if nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null | head -1 | grep -q H200; then
  export ADVISE_PROFILE=${ADVISE_PROFILE:-h200_x4}
fi
echo "profile ${ADVISE_PROFILE:-h100_x4}" >> "$out/log.txt"
{ nvidia-smi --query-gpu=index,name,driver_version,pci.bus_id --format=csv; $py -m mgpusim devices; } \
  > "$out/devices.txt" 2>&1
for try in 1 2; do
  left=$((deadline - SECONDS)); [ $left -lt 0 ] && left=0
  s=$SECONDS
  timeout "$((limit - SECONDS > 30 ? limit - SECONDS : 30))" $py $script --out "$out" --deadline-s "$left" "$@" \
    >> "$out/stdout.txt" 2>&1
  rc=$?
  echo "process try=$try rc=$rc $((SECONDS - s)) s" | tee -a "$out/log.txt"
  [ $rc = 0 ] && break
  [ $SECONDS -gt "$deadline" ] && break
done
$py $script --out "$out" --collect >> "$out/stdout.txt" 2>&1
cat "$out/summary.txt" 2>/dev/null
echo "total $SECONDS s" | tee -a "$out/log.txt"
