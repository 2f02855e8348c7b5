#!/usr/bin/env bash
# On an NVIDIA device machine: measure the lavapipe study on two of its CPU cores (one thread
# of each of two distinct physical cores), the setting of the 2-core development machine.
# Needs .gl, .whl (with tqdm and tomli_w), .lvp (scripts/bundle_lavapipe.sh) and .spvcache.
# Usage: [CORES=a,b] [GATE=0.12] bash scripts/device_lavapipe_job.sh OUTDIR [study measure args...]
# (default: the two highest-numbered CPUs of distinct cores). With GATE (a fraction), the job
# runs only if the speed probe's checks before it agree within it (`--steady-check`): a machine
# whose speed moves more gives errors that say nothing about the model.
set -euo pipefail
out=$1; shift
source .gl/env.sh; source .lvp/env.sh
export PYTHONPATH=$PWD:$PYTHONPATH MGPUSIM_CACHE=$PWD/.spvcache
mkdir -p "$out"
cores=${CORES:-$(python3 - <<'PY'
import os
seen, pick = set(), []
for cpu in sorted(os.sched_getaffinity(0), reverse=True):
    base = f"/sys/devices/system/cpu/cpu{cpu}/topology/"
    core = (open(base + "physical_package_id").read().strip(), open(base + "core_id").read().strip())
    if core not in seen:
        seen.add(core); pick.append(cpu)
    if len(pick) == 2:
        break
print(",".join(map(str, sorted(pick))))
PY
)}
{ echo "cores: $cores"; lscpu; nvidia-smi -L || true; } > "$out/machine.txt" 2>&1
echo "pinned to CPUs $cores"
taskset -c "$cores" python3 -m mgpusim devices | tee "$out/devices.txt"
taskset -c "$cores" python3 -m mgpusim study measure experiments/lavapipe/study.toml --out "$out/job" \
    ${GATE:+--steady-check "$GATE"} "$@"
