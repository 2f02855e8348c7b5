#!/usr/bin/env bash
# Per-pass costs on one NVIDIA GPU. Run from the project root on the device machine:
#   source .gl/env.sh; export PYTHONPATH=$PWD:$PYTHONPATH; MGPUSIM_CACHE=$PWD/.spvcache bash data/nvidia/measure.sh $OUT
# (.spvcache holds SPIR-V compiled here: the device machine has no glslc.)
set -u
out=${1:?output folder}
py=${PYTHON:-python3}
mkdir -p "$out"
m() { local name=$1; shift; timeout 150 $py -m mgpusim.cli measure --quiet --reps 10 --warmup 3 "$@" --out "$out/$name.csv" || echo "FAILED: $name"; }
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1; cat "$out/devices.txt"
m fragment_loop --pass fragment_loop --sweep iterations=1000,10000,100000 --sweep height=192,384,768
m mesh --pass mesh --sweep triangles=100000,1000000,4000000
m composite_sort_first --pass composite_sort_first --sweep inputs=2,4 --sweep width=1024,3840 --sweep height=768,2160
m composite_sort_last --pass composite_sort_last --sweep inputs=2,4 --sweep width=1024,3840 --sweep height=768,2160
m particle_update --pass particle_update --sweep particles=4096,65536,1048576
m particle_render --pass particle_render --sweep particles=4096,65536,1048576
for c in copy_d2h copy_h2d copy_d2d; do
  m $c --pass $c --sweep bytes=1MiB,16MiB,256MiB --sweep queue=graphics,transfer
done
m host_copy --pass host_copy --sweep bytes=16MiB,256MiB --sweep threads=1,4,16
m fragment_loop_2gpus --pass fragment_loop --gpus 2 --sweep iterations=10000,100000
ls -la "$out"
