#!/usr/bin/env bash
# Per-pass costs on lavapipe (small sizes: a CPU renders them). From the project root:
#   bash data/lavapipe/measure.sh data/lavapipe
set -u
out=${1:?output folder}
py=${PYTHON:-.venv/bin/python}
mkdir -p "$out"
m() { local name=$1; shift; $py -m mgpusim.cli measure --quiet --reps 5 --warmup 2 "$@" --out "$out/$name.csv" || echo "FAILED: $name"; }
$py -m mgpusim.cli devices > "$out/devices.txt" 2>&1
m fragment_loop --pass fragment_loop --sweep width=256 --sweep height=96,192 --sweep iterations=100,1000,10000
m mesh --pass mesh --sweep width=256 --sweep height=192 --sweep triangles=1000,10000,100000
m composite_sort_first --pass composite_sort_first --sweep inputs=2,4 --sweep width=512,1024 --sweep height=384,768
m composite_sort_last --pass composite_sort_last --sweep inputs=2,4 --sweep width=512,1024 --sweep height=384,768
m particle_update --pass particle_update --sweep particles=1024,16384,65536
m particle_render --pass particle_render --sweep width=512 --sweep height=384 --sweep particles=1024,16384,65536
for c in copy_d2h copy_h2d copy_d2d; do
  m $c --pass $c --sweep bytes=256KiB,4MiB,32MiB --sweep queue=graphics,transfer
done
m host_copy --pass host_copy --sweep bytes=4MiB,32MiB --sweep threads=1,2
m fragment_loop_2gpus --pass fragment_loop --gpus 2 --lp-threads 1 --sweep width=256 --sweep height=192 --sweep iterations=1000,10000
