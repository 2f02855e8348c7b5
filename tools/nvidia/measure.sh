#!/usr/bin/env bash
# The 4x H100 study's measurements, on the device machine, from the project root:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; export MGPUSIM_CACHE=$PWD/.spvcache
#   SWEEPS=1 bash tools/nvidia/measure.sh /tmp/work GROUP...
# (STUDY_DIR=experiments/h200_x4 or another study's folder, DEVICES=0,1 on two GPUs: the same for
# the study of that folder, on its machine)
# (carrying .gl, .whl with tomli_w and .spvcache filled here: the machine has no glslc).
# SWEEPS=1: first the machine (nvidia-smi, topology, lscpu, Vulkan devices and device groups) and
# the pass tables (`mgpusim measure`, one process per table; copies also with 2 and 4 GPUs
# copying at once); SWEEPS=mesh: the mesh tables only; SWEEPS=particles: the particle update
# and draw tables only. Then each GROUP (a regular expression searched in the configuration names,
# as `--only` takes it: a substring, or ^sf_ for the names that start so) in its own process:
# `mgpusim study measure` from a copy of study.toml without the committed tables and runs.
# One process per group, so that each group's runs are packed into $OUT as soon as it is done
# and a failed group is taken again once. (The groups began as a way round the NVIDIA driver's
# refusing a new VkInstance after about 30 in one process; the runner now keeps one instance
# for real GPUs, and one process takes a whole study.) A group already done
# (WORK/logs/groups.txt) is skipped; no group starts after DEADLINE_S seconds. WORK is tarred
# into $OUT after each step, so what was measured comes back even if the call is cut short.
# The runs use the runner's native core (MGPUSIM_RUNNER=auto picks it on real GPUs); the 2x H100,
# 4x H100 and 2x H200 studies' committed runs were made with the Python executor
# (MGPUSIM_RUNNER=python measures them so again).
# EXPECT_GPU=H100: stop at once (exit 3, the cards named) unless every card's name has it: a
# request for one kind of machine may be answered by another, whose runs would not belong here.
set -u
work=${1:?work folder}; shift
py=${PYTHON:-python3}
deadline=${DEADLINE_S:-480}
devices=${DEVICES:-0,1,2,3}
here=${STUDY_DIR:-$(dirname "$0")/../../experiments/h100_x4}
card=$(basename "$here")
if [ -n "${EXPECT_GPU:-}" ]; then
  names=$(nvidia-smi --query-gpu=name --format=csv,noheader 2>&1)
  if [ -z "$names" ] || echo "$names" | grep -v -q -- "$EXPECT_GPU"; then
    echo "measure.sh: expected every card to be an $EXPECT_GPU, got: $(echo "$names" | tr '\n' ';')" >&2
    exit 3
  fi
fi
mkdir -p "$work/measurements/parts" "$work/logs"
pack() { if [ -n "${OUT:-}" ]; then tar czf "$OUT/${card}_${TAG:-work}.tgz" -C "$work" . ; fi; }
m() { local out=$1; shift; timeout 150 $py -m mgpusim measure --quiet --reps 5 --warmup 2 "$@" \
        --out "$work/measurements/$out" >> "$work/logs/sweeps.log" 2>&1 || echo "FAILED: $out $*" >> "$work/logs/sweeps.log"; }

if [ "${SWEEPS:-0}" = 1 ]; then
  { nvidia-smi --query-gpu=name,driver_version,pci.bus_id,pcie.link.gen.max,pcie.link.width.max,memory.total --format=csv
    nvidia-smi topo -m; nvidia-smi; } > "$work/nvidia-smi.txt" 2>&1
  lscpu > "$work/lscpu.txt" 2>&1
  { $py -m mgpusim devices; $py "$(dirname "$0")/device_groups.py"; } > "$work/devices.txt" 2>&1
  s=$SECONDS
  m fragment_loop.csv --pass fragment_loop --sweep width=1920,3840 --sweep height=1080,2160 --sweep iterations=250,1000,4000
  m filter.csv --pass filter --sweep width=1920,3840 --sweep height=1080,2160 --sweep iterations=100,500 --sweep inputs=1,2,3
  m present.csv --pass present --sweep width=1920,2560,3840 --sweep height=1080,1440,2160
  for c in d2h h2d; do for g in 1 2 4; do
    m parts/copy_${c}_g$g.csv --pass copy_$c --gpus $g --sweep bytes=1MiB,16MiB,64MiB --sweep queue=graphics,transfer
  done; done
  m parts/copy_d2d_g1.csv --pass copy_d2d --sweep bytes=1MiB,16MiB,64MiB --sweep queue=graphics,transfer
  m host_copy.csv --pass host_copy --sweep bytes=4MiB,16MiB,64MiB --sweep threads=1,4,8,16
  echo "sweeps took $((SECONDS - s)) s" >> "$work/logs/sweeps.log"
  pack
fi
if [ "${SWEEPS:-0}" = 1 ] || [ "${SWEEPS:-0}" = mesh ]; then
  # The mesh after 30 warm-up draws: with 2, the first draws of a freshly built mesh of millions of
  # triangles ran up to 3-7x slower, for 100-300 ms (sometimes all 7 draws of a point), in the
  # first call's tables (logs/sweeps.log); the runner's runs warm up 8 frames and compare their
  # steady window.
  s=$SECONDS
  for size in 1920x1080 3840x2160; do
    m mesh_${size#*x}.csv --pass mesh --warmup 30 --sweep width=${size%x*} --sweep height=${size#*x} \
      --sweep triangles=3000000,10000000,20000000 --sweep place=whole,share=0/4,share=3/4,share=1/3
  done
  m mesh_xr.csv --pass mesh --warmup 30 --sweep width=2064,2880 --sweep height=2208,2720 \
    --sweep triangles=1000000,3000000,12000000 --sweep "place=whole,eye=left,eye=right;column=1/2"
  echo "mesh sweeps took $((SECONDS - s)) s" >> "$work/logs/sweeps.log"
  pack
fi

if [ "${SWEEPS:-0}" = 1 ] || [ "${SWEEPS:-0}" = particles ]; then
  # The particle update and draw, for the particle offload runs on two of the four GPUs.
  s=$SECONDS
  m particle_update.csv --pass particle_update --sweep particles=16384,65536,262144
  m particle_render.csv --pass particle_render --sweep width=1920,3840 --sweep height=1080,2160 \
    --sweep particles=16384,65536,262144
  echo "particle sweeps took $((SECONDS - s)) s" >> "$work/logs/sweeps.log"
  pack
fi

study=$here/study_measure.toml  # vanishes with the machine's copy of the tree
grep -v -e '^runs = ' -e '^tables = ' -e '^files = ' -e '^host_copy_table = ' $here/study.toml > "$study"
for g in "$@"; do
  if grep -q "^$g rc=0" "$work/logs/groups.txt" 2>/dev/null; then continue; fi
  if [ "$SECONDS" -gt "$deadline" ]; then echo "$g skipped at ${SECONDS}s" >> "$work/logs/groups.txt"; continue; fi
  for try in 1 2; do
    s=$SECONDS
    $py -m mgpusim study measure "$study" --devices "$devices" --held-out --only "$g" \
      --out "$work/study" > "$work/logs/measure_${g//[^A-Za-z0-9_]/}_$try.log" 2>&1
    rc=$?
    echo "$g rc=$rc try=$try $((SECONDS - s))s" >> "$work/logs/groups.txt"
    [ $rc = 0 ] && break
    [ "$SECONDS" -gt "$deadline" ] && break
  done
  pack
done
pack
