"""A CPU-emulated machine's profile at another speed of its host: the profile transformation
behind speed-normalized prediction (docs/validation.md, "Speed-normalized prediction").

Why: on lavapipe every GPU is the host's own CPU, and a shared virtual machine runs 10-130 %
slower or faster within minutes (the hypervisor's steal, the host's clock). A profile
calibrated at one speed then predicts a run measured at another with that ratio as error. A
reference pass timed beside each run (:mod:`mgpusim.measure.speed_probe`) says how much slower
the machine was then; `at_speed` turns the calibrated profile into the one for that moment.

What scales (times `scale`, rates over `scale`): everything that is CPU work on lavapipe.
  * every pass's cost (fixed and per-work terms, through the GPU's `speed`) and the driver's
    CPU work around it (`cpu_overhead_ns`): shading and binning are the host's instructions;
  * every copy: the fixed cost of a copy command and the rates of the d2h / h2d / d2d paths
    and any per-queue caps (lavapipe copies are memcpy on its queue thread);
  * the host copies (memcpy threads' and host memory's rates, their fixed cost), the submit
    thread's work per task (`submit_ns`), the host's dispatch work (`dispatch_ns`), the
    queue's work between two tasks (`task_gap_ns`) and the application threads' work
    (`record_ns`, `thread_start_ns`): instructions on the same cores.
What does not: fractions and counts (`cores`, overlap and oversubscription efficiencies, the
busy_wake share, thread counts, memory sizes), and the waits that are the kernel's timing rather
than work (`host_copy_wake_ns`, a sleeping thread's wake-up; `busy_wake_ns` and its window, the
scheduler's balancing interval; link latencies; a host PCIe channel's rates, which lavapipe has
none of). A real GPU's passes do not run on the host CPU, so such a profile is refused.
"""
from __future__ import annotations

import math
from dataclasses import replace
from types import MappingProxyType

from mgpusim.model.errors import InputError
from mgpusim.model.profile import CopyCosts, GpuProfile, HardwareProfile, HostProfile, PassCost

#: A scale outside this range is not a machine's speed but a broken probe.
MIN_SCALE, MAX_SCALE = 0.05, 20.0


def at_speed(profile: HardwareProfile, scale: float) -> HardwareProfile:
    """`profile` on its host running `scale` times slower (2.0: every CPU-work cost doubled,
    every CPU-driven rate halved; 1.0: the profile itself). See the module docstring for what
    scales and why. InputError for a profile whose GPUs are not the host's CPU, or a scale that
    is not a positive, finite number within MIN_SCALE..MAX_SCALE."""
    if not profile.host.gpus_share_cpu:
        raise InputError(f"speed normalization scales CPU work, and profile {profile.name!r} "
                         "has GPUs of their own (host.gpus_share_cpu is false)",
                         file=profile.source, field="host.gpus_share_cpu")
    if not (isinstance(scale, (int, float)) and math.isfinite(scale)
            and MIN_SCALE <= scale <= MAX_SCALE):
        raise InputError(f"expected a speed scale between {MIN_SCALE} and {MAX_SCALE} (the probe "
                         f"at the run over the probe at calibration), got {scale!r}",
                         field="speed scale")
    if scale == 1.0:
        return profile
    return replace(profile, host=_host(profile.host, scale),
                   gpus=tuple(_gpu(g, scale) for g in profile.gpus))


def _ns(value: float, scale: float) -> int:
    """A duration in integer ns, scaled and rounded half up (the model's rounding rule)."""
    return int(math.floor(value * scale + 0.5))


def _host(host: HostProfile, scale: float) -> HostProfile:
    return replace(
        host,
        memory_bandwidth_gbps=host.memory_bandwidth_gbps / scale,
        memcpy_thread_gbps=host.memcpy_thread_gbps / scale,
        uncached_read_gbps=host.uncached_read_gbps / scale,
        host_copy_fixed_ns=_ns(host.host_copy_fixed_ns, scale),
        dispatch_ns=_ns(host.dispatch_ns, scale),
        submit_ns=_ns(host.submit_ns, scale),
        thread_start_ns=_ns(host.thread_start_ns, scale),
        record_ns=_ns(host.record_ns, scale))


def _gpu(gpu: GpuProfile, scale: float) -> GpuProfile:
    link = replace(gpu.link, h2d_gbps=gpu.link.bandwidth_gbps("h2d") / scale,
                   d2h_gbps=gpu.link.bandwidth_gbps("d2h") / scale)
    return replace(
        gpu, speed=gpu.speed / scale, link=link, local_copy_gbps=gpu.local_copy_gbps / scale,
        task_gap_ns=_ns(gpu.task_gap_ns, scale),
        costs=MappingProxyType({k: _pass(c, scale) for k, c in gpu.costs.items()}),
        copy=MappingProxyType({k: _copy(c, scale) for k, c in gpu.copy.items()}))


def _pass(cost: PassCost, scale: float) -> PassCost:
    """The driver's CPU work around the pass; the pass itself scales through the GPU's speed."""
    return replace(cost, cpu_overhead_ns=cost.cpu_overhead_ns * scale)


def _copy(copy: CopyCosts, scale: float) -> CopyCosts:
    return replace(copy, fixed_ns=_ns(copy.fixed_ns, scale),
                   caps_gbps=MappingProxyType({p: v / scale for p, v in copy.caps_gbps.items()}))
