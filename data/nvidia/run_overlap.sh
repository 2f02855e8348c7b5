#!/usr/bin/env bash
# Queues sharing ONE NVIDIA GPU (an H100): the overlap microbenchmark (two pieces of work on two
# queues alone and at once: graphics+compute, graphics+copy engine, compute+copy engine, and two
# VkDevices on the one GPU), the particle passes at the run's sizes, and particle offload on the
# one GPU: the update on the graphics queue, on the compute queue (async compute), and on a
# second logical GPU (a second VkDevice on the same GPU). Everything lands in FOLDER, packed into
# TARBALL_DIR/queues.tar.gz (the device tool brings back few files); unpack it into
# data/nvidia/h100_x1/queues/ for experiments/h100/queues.toml. Under 6 minutes. From the project
# root on the device machine (carrying .gl, .whl and .spvcache, SPIR-V compiled here):
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; export MGPUSIM_CACHE=$PWD/.spvcache; bash data/nvidia/run_overlap.sh /tmp/queues $OUT
set -u
out=${1:?work folder}; pack=${2:-}; py=${PYTHON:-python3}; mkdir -p "$out/runs"
exp=experiments/h100/particles.toml
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1; head -5 "$out/devices.txt"
nvidia-smi > "$out/nvidia-smi.txt" 2>&1
m() {  # name measure-arguments...: 5 repetitions kept after 3 warm-ups, on physical device 0
  local name=$1; shift
  timeout 120 $py -m mgpusim.cli measure --reps 5 --warmup 3 --device 0 "$@" --out "$out/$name.csv" \
    > "$out/$name.log" 2>&1; echo "$name rc=$?"
}
pairs=pair=graphics_compute,graphics_transfer,compute_transfer,devices
# the run's sizes: the shadow pass (640x360, 7000 iterations) against the update of 2M
# particles, and a 384 MiB upload (2M particles x 192 B) on the copy engine; then all doubled
m overlap_2m --pass overlap --sweep $pairs --sweep width=640 --sweep height=360 --sweep iterations=7000 \
  --sweep particles=2097152 --sweep bytes=384MiB --sweep copy=h2d
m overlap_4m --pass overlap --sweep $pairs --sweep width=640 --sweep height=360 --sweep iterations=14000 \
  --sweep particles=4194304 --sweep bytes=768MiB --sweep copy=h2d
m overlap_d2h --pass overlap --sweep pair=graphics_transfer --sweep width=640 --sweep height=360 \
  --sweep iterations=7000 --sweep bytes=384MiB --sweep copy=d2h,d2d
cat "$out/overlap_2m.log" "$out/overlap_4m.log" "$out/overlap_d2h.log"
m particle_update --pass particle_update --sweep particles=524288,2097152,4194304
m particle_render --pass particle_render --sweep width=640 --sweep height=360 --sweep particles=524288,2097152,4194304
m fragment_loop_640 --pass fragment_loop --sweep width=640 --sweep height=360 --sweep iterations=7000,10000,14000
run() {  # name [run options] -- sets...: the study's configuration, measured
  local name=$1; shift; local opts=(); while [ "$1" != "--" ]; do opts+=("$1"); shift; done; shift
  local sets=(); for s in "$@"; do sets+=(--set "$s"); done
  timeout 150 $py -m mgpusim.cli run "$exp" "${opts[@]}" --prewarm 4 "${sets[@]}" --out "$out/runs/$name" \
    > "$out/runs/$name.log" 2>&1
  echo "$name rc=$? $(grep -o 'frame time [0-9.]* ms' "$out/runs/$name.log" | head -1)"
}
two=(schedule.gpus=2 schedule.particle_gpu=1 profile.gpu_count=2 profile.gpus.0.physical=0)
run p2m_graphics -- 'schedule.update_queue="graphics"'
run p2m_compute --
run p4m_compute -- schedule.particles=4194304
run p4m_graphics -- schedule.particles=4194304 'schedule.update_queue="graphics"'
run p2m_2dev_wait --gpus-per-device 2 -- "${two[@]}"
run p2m_2dev_new_wait --gpus-per-device 2 -- "${two[@]}" 'schedule.policy="new_wait"'
run p2m_2dev_nohost --gpus-per-device 2 -- "${two[@]}" schedule.host_copy=false
if [ -n "$pack" ]; then
  tar czf "$pack/queues.tar.gz" -C "$out" . && ls -la "$pack/queues.tar.gz"
  tail -n 20 "$out"/*.log "$out"/runs/*.log > "$pack/logs.txt" 2>&1
fi
