"""CPU time per runner task on one thread: the per-task Vulkan calls through the `vulkan`
binding's wrappers against the same calls made straight on the C library (the runner's way,
`mgpusim/real/vulkan/hotpath.py`).

    PYTHONPATH=. python benchmarks/submit_overhead.py [--tasks 3000] [--device 0]

A task here is what the runner does for every GPU task once its command buffer is recorded:
submit it, wait for its fence, read its two timestamps, reset the fence. The command buffer is
empty between its timestamps, so what is left is the host's cost, Python and driver. Both ways
run on the same pre-recorded slot; the first lavapipe device unless --device says otherwise.
Measured on the 2-core development VM (lavapipe, 2026-11-27, three runs as its speed moved):
75 / 112 / 136 us through the binding, 22 / 54 / 57 us straight: the wrappers were half or more
of a task's host cost. On lavapipe the straight way now reads the stamps the command buffer
copied to memory instead of calling vkGetQueryPoolResults (docs/runner.md): two runs later that
day, 68 / 95 us through the binding, 18 / 27 us straight.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.real.vulkan import hotpath  # noqa: E402
from mgpusim.real.vulkan.vk_errors import vk  # noqa: E402


def _through_binding(gpu, queue, slot) -> None:
    """The four calls as the runner made them before hotpath.py."""
    v = vk()
    info = v.VkSubmitInfo(waitSemaphoreCount=0, pWaitSemaphores=None, pWaitDstStageMask=None,
                          commandBufferCount=1, pCommandBuffers=[slot.cmd],
                          signalSemaphoreCount=0, pSignalSemaphores=None)
    v.vkQueueSubmit(queue.handle, 1, [info], slot.fence)
    v.vkWaitForFences(gpu.device, 1, [slot.fence], v.VK_TRUE, 10**10)
    data = v.ffi.new("uint64_t[2]")
    v.vkGetQueryPoolResults(gpu.device, slot.pool, 0, 2, 16, data, 8,
                            v.VK_QUERY_RESULT_64_BIT | v.VK_QUERY_RESULT_WAIT_BIT)
    v.vkResetFences(gpu.device, 1, [slot.fence])


def _straight(gpu, queue, slot) -> None:
    hotpath.submit(queue.handle, slot)
    hotpath.wait_fence(gpu.device, slot, 10**10)
    hotpath.read_ticks(gpu.device, slot)
    hotpath.reset_fence(gpu.device, slot)


def cpu_us_per_task(way: Callable[..., None], gpu, queue, slot, tasks: int) -> float:
    """Mean CPU time of this thread per task, after a few untimed ones."""
    for _ in range(min(50, tasks)):
        way(gpu, queue, slot)
    start = time.thread_time_ns()
    for _ in range(tasks):
        way(gpu, queue, slot)
    return (time.thread_time_ns() - start) / tasks / 1e3


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", type=int, default=3000)
    ap.add_argument("--device", type=int, default=0)
    args = ap.parse_args(argv)
    if args.tasks < 1:
        ap.error("--tasks must be >= 1")
    from mgpusim.real.runner.gpu_map import open_gpus
    from mgpusim.real.vulkan.machine import close_gpus

    gpus = open_gpus(1, devices=[args.device])
    try:
        gpu = gpus[0]
        queue = gpu.queue("graphics")
        gpu.submit(queue, lambda cmd: None, label="recorded once", key="bench").wait()
        slot = queue.recorded["bench"].pop()
        try:
            results = {name: cpu_us_per_task(way, gpu, queue, slot, args.tasks)
                       for name, way in (("through the binding", _through_binding),
                                         ("straight (hotpath.py)", _straight))}
        finally:
            queue.recorded["bench"].append(slot)
        print(f"{gpu.info.name}: CPU per task over {args.tasks} tasks")
        for name, us in results.items():
            print(f"  {name:22s} {us:7.1f} us")
    finally:
        close_gpus(gpus)
    return 0


if __name__ == "__main__":
    sys.exit(main())
