#!/usr/bin/env bash
# On an NVIDIA device machine: measure the lavapipe study on two of its CPU cores (one thread
# of each of two distinct physical cores), the setting of the 2-core development machine.
# Needs .gl, .whl (with tqdm and tomli_w), .lvp (scripts/bundle_lavapipe.sh) and .spvcache.
# Usage: [CORES=a,b] [GATE=0.12] bash scripts/device_lavapipe_job.sh OUTDIR [study measure args...]
# (default: the two highest-numbered CPUs of distinct cores). With GATE, the job runs only if
# the speed probe's six checks before it (a minute) spread by at most that fraction per pass:
# a machine whose speed moves that much gives errors that say nothing about the model.
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
taskset -c "$cores" python3 - "${GATE:-}" <<'PY' | tee "$out/speed_check.txt"
import sys, time
from mgpusim.study.speed import measure_probe
gate = float(sys.argv[1]) if sys.argv[1] else None
times: dict[str, list[float]] = {}
for i in range(6 if gate is not None else 3):
    rows = measure_probe("check", 8)
    print([(x["pass"], round(x["median_ms"], 3)) for x in rows], flush=True)
    for x in rows:
        times.setdefault(x["pass"], []).append(x["median_ms"])
    time.sleep(5)
spread = {k: max(v) / min(v) - 1 for k, v in times.items()}
print("spread:", {k: round(v, 3) for k, v in spread.items()})
if gate is not None and max(spread.values()) > gate:
    sys.exit(f"the machine's speed moved more than {gate:.0%} before the job: not run")
PY
taskset -c "$cores" python3 -m mgpusim study measure experiments/lavapipe/study.toml --out "$out/job" "$@"
