"""Device timestamp ticks -> host-clock nanoseconds (CLOCK_MONOTONIC, i.e. time.monotonic_ns()).

Why: timestamps of different physical devices run on different clocks (docs/vulkan.md: binding traps), and the
runner puts every queue of every simulated GPU on one timeline. With VK_KHR/EXT_calibrated_
timestamps we sample (device, CLOCK_MONOTONIC) pairs and keep the offset; lavapipe's ticks are
already CLOCK_MONOTONIC, so its offset comes out ~0. Without the extension the offset is
estimated from one timestamp-only submission (coarse: half its round trip).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Protocol

from mgpusim.real.vulkan.vk_errors import call, vk


class Gpu(Protocol):
    """What the clock calibration needs of a GPU (:class:`mgpusim.real.vulkan.device.Gpu`), named
    here because the device calibrates its clock when it opens: importing it back would be a
    cycle."""

    info: Any
    enabled_extensions: list[str]
    instance: Any
    physical: Any
    device: Any

    def proc(self, name: str) -> Any: ...

    def submit(self, queue: Any, record: Any) -> Any: ...

    def queue(self, kind: Any) -> Any: ...


@dataclass
class Clock:
    """host_ns = offset_ns + ticks * period_ns (ticks masked to the valid bits)."""

    period_ns: float
    offset_ns: float
    valid_bits: int
    method: str  # "calibrated" | "monotonic" | "estimated"
    max_deviation_ns: float = 0.0

    def to_host_ns(self, ticks: int) -> int:
        if self.valid_bits < 64:
            ticks &= (1 << self.valid_bits) - 1
        return int(round(self.offset_ns + ticks * self.period_ns))


def _calibrated(gpu: Gpu, period: float, bits: int, samples: int = 5) -> Clock | None:
    v = vk()
    lib = v.lib
    ext = gpu.info.calibrated_timestamps
    if ext is None or ext not in gpu.enabled_extensions:
        return None
    suffix = "KHR" if ext.startswith("VK_KHR") else "EXT"
    domains_fn = gpu.instance.proc(f"vkGetPhysicalDeviceCalibrateableTimeDomains{suffix}")
    domains = set(call("vkGetPhysicalDeviceCalibrateableTimeDomains", domains_fn,
                       gpu.physical))
    if not {lib.VK_TIME_DOMAIN_DEVICE_EXT, lib.VK_TIME_DOMAIN_CLOCK_MONOTONIC_EXT} <= domains:
        return None
    get = gpu.proc(f"vkGetCalibratedTimestamps{suffix}")
    stype = lib.VK_STRUCTURE_TYPE_CALIBRATED_TIMESTAMP_INFO_EXT
    dev_info = v.VkCalibratedTimestampInfoKHR(sType=stype, timeDomain=lib.VK_TIME_DOMAIN_DEVICE_EXT)
    host_info = v.VkCalibratedTimestampInfoKHR(sType=stype,
                                               timeDomain=lib.VK_TIME_DOMAIN_CLOCK_MONOTONIC_EXT)
    infos = [dev_info, host_info]
    best: tuple[int, float] | None = None
    for _ in range(samples):  # keep the sample with the smallest deviation
        stamps = v.ffi.new("uint64_t[2]")
        deviation = v.ffi.new("uint64_t*")
        call("vkGetCalibratedTimestamps", get, gpu.device, 2, infos, stamps, deviation)
        if best is None or deviation[0] < best[0]:
            best = (int(deviation[0]), stamps[1] - stamps[0] * period)
    assert best is not None
    return Clock(period, best[1], bits, "calibrated", float(best[0]))


def _estimated(gpu: Gpu, period: float, bits: int) -> Clock:
    before = time.monotonic_ns()
    sub = gpu.submit("graphics", lambda cmd: None)
    sub.wait()
    after = time.monotonic_ns()
    ticks = sub.raw_ticks()[0]
    return Clock(period, (before + after) / 2 - ticks * period, bits, "estimated",
                 (after - before) / 2)


def calibrate(gpu: Gpu) -> Clock:
    """The clock of `gpu`'s graphics queue family mapped to time.monotonic_ns()."""
    period = gpu.info.timestamp_period
    bits = gpu.queue("graphics").family.timestamp_valid_bits
    clock = _calibrated(gpu, period, bits)
    if clock is not None:
        return clock
    if gpu.info.is_lavapipe:
        return Clock(period, 0.0, bits, "monotonic")
    return _estimated(gpu, period, bits)
