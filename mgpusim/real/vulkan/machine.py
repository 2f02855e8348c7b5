"""Simulated GPUs on the machine at hand, and the machine record written beside measurements.

Why here: how simulated GPUs map onto real devices differs by driver. On lavapipe each simulated
GPU is its own VkInstance (own rasterizer thread pool, optional LP_NUM_THREADS each); elsewhere
one VkInstance, and simulated GPU i gets physical device i mod count (several simulated GPUs on
one real GPU when there are fewer real ones, as the XR sample's simulate mode does).
"""
from __future__ import annotations

import atexit
import datetime as _dt
import os
import platform
from importlib import metadata
from typing import Any, Sequence

from mgpusim.model.errors import InputError
from mgpusim.real.host import priority as host_priority
from mgpusim.real.host.heap import keep_heap
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.instance import Instance, validation_wanted

#: The VkInstance of real (not CPU-emulated) GPUs, one per validation setting, kept for the
#: process. Why: the NVIDIA driver (580.159) refuses a new instance once about 30 have been
#: created and destroyed in one process (VkErrorIncompatibleDriver at a study's 31st run, with
#: no file, thread or mapping left behind), so runs share one. Lavapipe GPUs keep an instance
#: each: each sizes its own rasterizer pool (LP_NUM_THREADS) when it is made.
_REAL_INSTANCES: dict[bool, Instance] = {}


def instance_for(validation: bool | None, lp_num_threads: int | None) -> Instance:
    """The kept instance of real GPUs where there is one, else a new instance (kept if its
    devices are real)."""
    kept = _REAL_INSTANCES.get(validation_wanted(validation))
    if kept is not None:
        return kept
    inst = Instance(validation=validation, lp_num_threads=lp_num_threads)
    if inst.devices and not any(d.is_lavapipe for d in inst.devices):
        if not _REAL_INSTANCES:
            atexit.register(_close_kept)
        _REAL_INSTANCES[inst.validation] = inst
    return inst


def _close_kept() -> None:
    for inst in _REAL_INSTANCES.values():
        inst.close()
    _REAL_INSTANCES.clear()


def is_kept(inst: Instance) -> bool:
    """Whether `inst` is the process's kept instance of real GPUs (closed only at exit)."""
    return any(k is inst for k in _REAL_INSTANCES.values())


def make_gpus(n: int, *, lp_threads: Sequence[int | None] | None = None,
              physical: int | None = None, validation: bool | None = None) -> list[Gpu]:
    """`n` simulated GPUs. `lp_threads[i]` sets LP_NUM_THREADS of GPU i (lavapipe only);
    `physical` pins every simulated GPU to one physical device."""
    if n < 1:
        raise InputError(f"need at least one GPU, got {n}", field="gpus")
    threads = list(lp_threads) if lp_threads is not None else [None] * n
    if len(threads) == 1 and n > 1:
        threads *= n
    if len(threads) != n:
        raise InputError(f"{len(threads)} thread counts for {n} GPUs", field="lp_threads")
    first = instance_for(validation, threads[0])
    pick = physical if physical is not None else 0
    if not 0 <= pick < len(first.devices):
        if not is_kept(first):
            first.close()
        raise InputError(f"no physical device {pick}; found {len(first.devices)}",
                         field="device")
    gpus: list[Gpu] = []
    try:  # a failure part-way closes what was opened
        if first.devices[pick].is_lavapipe:
            gpus.append(Gpu(first, pick, "gpu0", owns_instance=True))
            for i in range(1, n):
                inst = Instance(validation=validation, lp_num_threads=threads[i])
                try:
                    gpus.append(Gpu(inst, pick, f"gpu{i}", owns_instance=True))
                except BaseException:
                    inst.close()
                    raise
            return gpus
        count = len(first.devices)
        for i in range(n):
            gpus.append(Gpu(first, physical if physical is not None else i % count, f"gpu{i}"))
        return gpus
    except BaseException:
        close_gpus(gpus)
        if not any(g.instance is first for g in gpus) and not is_kept(first):
            first.close()
        raise


def close_gpus(gpus: Sequence[Gpu]) -> None:
    """Close every GPU, then the shared instance (if the GPUs did not own theirs and it is
    not the one real GPUs keep for the process)."""
    shared = {id(g.instance): g.instance for g in gpus if not g.owns_instance and not is_kept(g.instance)}
    for gpu in gpus:
        gpu.close()
    for inst in shared.values():
        inst.close()


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _version(pkg: str) -> str | None:
    try:
        return metadata.version(pkg)
    except metadata.PackageNotFoundError:
        return None


def machine_record(gpus: Sequence[Gpu], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """CPU, OS, driver, thread counts and library versions: what a measurement depends on."""
    return {
        "recorded_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "affinity_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "libraries": {p: _version(p) for p in ("vulkan", "cffi", "numpy", "pandas", "pyarrow",
                                               "tqdm")},
        "env": {k: os.environ.get(k) for k in ("LP_NUM_THREADS", "VK_ICD_FILENAMES",
                                               "VK_DRIVER_FILES", "MGPUSIM_VK_VALIDATION",
                                               "MGPUSIM_KEEP_HEAP")},
        "host_heap": keep_heap(),
        "host_thread_priority": host_priority.status(),
        "gpus": [{
            "name": g.name, "device": g.info.name, "device_type": g.info.device_type,
            "physical_index": g.physical_index,
            "driver": g.info.driver_name, "driver_info": g.info.driver_info,
            "driver_version": g.info.driver_version, "api_version": g.info.api_version,
            "lp_num_threads": g.instance.lp_num_threads,
            "timestamp_period_ns": g.info.timestamp_period, "clock": g.clock.method,
            "clock_max_deviation_ns": g.clock.max_deviation_ns,
            "queues": {k: {"family": q.family.index, "dedicated": g.has_dedicated(k)}
                       for k, q in g.queues.items()},
            "external_memory_host": g.info.external_memory_host,
        } for g in gpus],
        **(extra or {}),
    }
