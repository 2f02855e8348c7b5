"""The runner keeps lavapipe's per-frame scene memory in the process (vulkan.hostheap).

Each case runs in a fresh interpreter: glibc's thresholds are process-wide and this one has
already set them. The measure is minor page faults per mesh frame after warm-up, not time,
so that it holds on a noisy machine.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.vulkan

SCRIPT = """
import resource, sys
from mgpusim.real.vulkan.machine import make_gpus, close_gpus
from mgpusim.real.passes.standalone import Mesh
gpus = make_gpus(1)
mesh = Mesh(gpus[0], 128, 96, 60000)
for _ in range(10):
    gpus[0].run(mesh.queue, mesh.record)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    gpus[0].run(mesh.queue, mesh.record)
after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
mesh.destroy()
close_gpus(gpus)
print((after - before) / 20)
"""


def faults_per_frame(keep: str) -> float:
    env = {**os.environ, "MGPUSIM_KEEP_HEAP": keep, "MGPUSIM_VK_VALIDATION": "0"}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                         text=True, timeout=120)
    if out.returncode != 0:
        pytest.fail(out.stderr[-2000:])
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.usefixtures("instance")  # skips where no Vulkan driver is found
def test_kept_heap_stops_faulting_the_scene_in_every_frame():
    kept, default = faults_per_frame("1"), faults_per_frame("0")
    # 60k triangles bin ~8 MB per frame at 128x96: ~2,100 pages when it is handed back and
    # faulted in again each frame (the control: without it this test could not fail).
    assert default > 1000, f"glibc defaults faulted only {default} pages per frame"
    assert kept < default / 10, f"{kept} page faults per frame with the heap kept ({default} without)"
