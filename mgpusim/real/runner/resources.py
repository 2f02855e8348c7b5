"""Allocating the schedule's logical resources on the simulated GPUs.

Why a table of names: the schedule declares every buffer and image its tasks touch
(`FrameProgram.resources`, :class:`mgpusim.model.tasks.Resource`); this module turns each into
`buffers` Vulkan objects on its device, so the task executors only ask "resource X, frame f".
Host memory shared by two devices (VK_EXT_external_memory_host) is one allocation imported into
each of them.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

from mgpusim.model.errors import InputError, ScheduleError
from mgpusim.model.tasks import Resource
from mgpusim.real.vulkan.buffers import DEPTH_FORMAT, Image
from mgpusim.real.vulkan.copies import clear_images
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.hostmem import SharedHostMemory

COLOR_BPP, DEPTH_BPP = 4, 2


class Resources:
    """Every declared resource, `buffers` copies each; frame f uses copy f % buffers."""

    def __init__(self, declared: Sequence[Resource], gpus: Sequence[Gpu]):
        self.declared = {r.name: r for r in declared}
        self.gpus = list(gpus)
        self._images: dict[str, list[tuple[Image, Image | None]]] = {}
        self._buffers: dict[tuple[str, int], list[Any]] = {}
        self._shared: list[SharedHostMemory] = []
        try:
            for res in declared:
                self._allocate(res)
        except BaseException:
            self.destroy()
            raise

    def _gpu(self, res: Resource, device: int | None) -> Gpu:
        if device is None or not 0 <= device < len(self.gpus):
            raise ScheduleError(f"resource {res.name!r} is on device {device}, but the run has "
                                f"{len(self.gpus)} GPU(s)")
        return self.gpus[device]

    def _allocate(self, res: Resource) -> None:
        if res.kind == "image":
            gpu = self._gpu(res, res.device)
            w, h = max(res.width, 1), max(res.height, 1)  # an empty tile still gets a 1-row image
            pairs = self._images[res.name] = []  # stored first: destroy() sees every image made
            for _ in range(res.buffers):
                colour = gpu.image(w, h)
                pairs.append((colour, None))
                if res.depth:
                    pairs[-1] = (colour, gpu.image(w, h, DEPTH_FORMAT))
            # defined contents before the first frame: a temporal pass's first history, a
            # frame no copy has reached yet
            made = [img for pair in pairs for img in pair if img is not None]
            gpu.run("graphics", lambda cmd: clear_images(cmd, made))
        elif res.device is None:
            owners = [self._gpu(res, d) for d in res.shared_by]
            for d in res.shared_by:
                self._buffers[(res.name, d)] = []
            for _ in range(res.buffers):
                mem = SharedHostMemory(max(res.bytes, 1), owners)
                self._shared.append(mem)
                for d, g in zip(res.shared_by, owners):
                    self._buffers[(res.name, d)].append(mem.buffer(g))
        else:
            gpu = self._gpu(res, res.device)
            bufs = self._buffers[(res.name, res.device)] = []  # stored first, as images are
            for _ in range(res.buffers):
                bufs.append(gpu.buffer(max(res.bytes, 1), host_visible=res.host_visible))

    @property
    def cycle(self) -> int:
        """Frames after which every resource is back at the same buffered copy."""
        return math.lcm(1, *(r.buffers for r in self.declared.values()))

    def slot(self, name: str, frame: int) -> int:
        return frame % self.resource(name).buffers

    def resource(self, name: str) -> Resource:
        if name not in self.declared:
            raise ScheduleError(f"a task names resource {name!r}, which the schedule does not "
                                f"declare (FrameProgram.resources)")
        return self.declared[name]

    def images(self, name: str) -> list[tuple[Image, Image | None]]:
        """(colour, depth or None) of every buffered copy of image resource `name`."""
        if name not in self._images:
            raise ScheduleError(f"resource {self.resource(name).name!r} is not an image")
        return self._images[name]

    def buffer(self, name: str, device: int, slot: int) -> Any:
        """Buffered copy `slot` of buffer `name` as seen by `device` (host-visible: `.array`)."""
        key = (name, device)
        if key not in self._buffers:
            raise ScheduleError(f"buffer {self.resource(name).name!r} is not visible to gpu{device}")
        return self._buffers[key][slot]

    def host_array(self, name: str, slot: int) -> Any:
        """The mapped bytes of host-visible buffer `name` (for host copies)."""
        res = self.resource(name)
        device = res.device if res.device is not None else res.shared_by[0]
        array = self.buffer(name, device, slot).array
        if array is None:
            raise InputError(f"buffer {name!r} is not host-visible")
        return array[:res.bytes]

    def destroy(self) -> None:
        """Images and buffers first, shared host memory (after all its imports) last."""
        for pairs in self._images.values():
            for colour, depth in pairs:
                colour.destroy()
                if depth is not None:
                    depth.destroy()
        for (name, _dev), bufs in self._buffers.items():
            if self.declared[name].device is not None:
                for b in bufs:
                    b.destroy()
        self._images.clear()
        self._buffers.clear()  # drop the views into shared host memory before unmapping it
        for mem in self._shared:
            mem.destroy()
        self._shared.clear()
