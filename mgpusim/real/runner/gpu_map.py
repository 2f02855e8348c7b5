"""Opening the simulated GPUs of a run, with an explicit physical device per GPU.

Why beside `vulkan.machine.make_gpus`: a measured multi-GPU run on NVIDIA wants "simulated GPU i
on physical device devices[i]" (one real GPU each, or several on one), which make_gpus only
offers as "all on one" or "i mod count". On lavapipe every simulated GPU is its own instance
either way (its own rasterizer pool), so `devices` is only checked there. Real GPUs share the
process's kept instance (`vulkan.machine.instance_for`): the NVIDIA driver refuses new instances
after about 30 in one process.
"""
from __future__ import annotations

from typing import Sequence

from mgpusim.model.errors import InputError
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.machine import close_gpus, instance_for, is_kept, make_gpus


def open_gpus(n: int, *, devices: Sequence[int] | None = None,
              lp_threads: Sequence[int | None] | None = None,
              validation: bool | None = None) -> list[Gpu]:
    """`n` simulated GPUs; `devices[i]` is GPU i's physical device (default: i mod count)."""
    if devices is None:
        return make_gpus(n, lp_threads=lp_threads, validation=validation)
    devices = list(devices)
    if len(devices) != n:
        raise InputError(f"{len(devices)} device indices for {n} GPUs", field="devices")
    first = instance_for(validation, None)
    bad = [d for d in devices if not 0 <= d < len(first.devices)]
    if bad:
        count = len(first.devices)
        if not is_kept(first):
            first.close()
        raise InputError(f"no physical device {bad[0]}; found {count}", field="devices")
    if first.devices[devices[0]].is_lavapipe:
        first.close()
        return make_gpus(n, lp_threads=lp_threads, physical=devices[0], validation=validation)
    gpus: list[Gpu] = []
    try:
        for i, d in enumerate(devices):
            gpus.append(Gpu(first, d, f"gpu{i}"))
    except BaseException:
        close_gpus(gpus)
        if not is_kept(first):
            first.close()
        raise
    return gpus
