"""Which buffer or image each five-step task reads and writes, for the Vulkan runner.

Why a separate pass over the tasks: the schedule's timing structure (five_step.py) stays as it
is, and this module adds the data a real renderer needs on top of it: the logical resources
(render targets, staging buffers, uploaded contributions, the frame and the displayed image),
the tile rectangle or geometry share of every render, the rectangles the composite draws. The
simulator ignores all of it.

Resource names: `gpu{i}.target` (secondary i's contribution), `gpu{i}.staging` (its host-visible
read-back buffer), `gpu0.staging{i}` (the primary's staging buffer for it; `host.staging{i}`, one
host allocation imported by both devices, when there is no host-to-host copy), `gpu0.input{i}`
(the uploaded contribution), `gpu0.frame` (the primary renders and composites into it) and
`gpu0.display` (what present copies the frame to).

A GPU's passes render into its target in order, the first clearing it; a pass that a later
filter samples renders into an image of its own instead, `gpu{i}.pass.{name}` (its tile's
rectangle, with depth for a mesh), and the filter samples those at its own pixel, so a tile's
filter is exact. A filter sampling its own previous output (pass_io.py) reads the target of the
previous frame, which is then double-buffered. A mesh drawn into the target gives it depth;
sort-first still moves colour only.
"""
from __future__ import annotations

import dataclasses
from types import MappingProxyType
from typing import Any

from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import CopyTask, HostCopyTask, PassTask, Resource, Task
from mgpusim.schedules.pass_io import filter_reads, filter_sources, read_params, reads_own_output, simulated_only

Rect = tuple[int, int, int, int]  # x, y, width, height in frame pixels


def bind_io(tasks: list[Task], scene: Scene, gpus: int, composite_kind: str,
            tile_rows: tuple[int, ...] | None, buffers: int, host_copy: bool,
            geometry: list[tuple[int, int, int]] | None = None
            ) -> tuple[list[Task], tuple[Resource, ...]]:
    """The tasks with reads/writes/src/dst/params filled in, and the resources they name;
    `geometry`: per GPU (first, end, units) of the mesh a sort-last GPU draws (default: an
    even split, GPU i draws [i, i + 1) of N units)."""
    binder = _Binder(scene, gpus, composite_kind, tile_rows, buffers, host_copy, geometry,
                     {t.name: t for t in tasks})
    return [binder.bind(task) for task in tasks], tuple(binder.res.values())


class _Binder:
    """The resources of one five-step run, named as the tasks are bound (each task kind by a
    method of its own): tile rectangles, targets, staging buffers and uploaded inputs."""

    def __init__(self, scene: Scene, gpus: int, composite_kind: str,
                 tile_rows: tuple[int, ...] | None, buffers: int, host_copy: bool,
                 geometry: list[tuple[int, int, int]] | None, by_name: dict[str, Task]):
        self.scene, self.gpus, self.buffers, self.host_copy = scene, gpus, buffers, host_copy
        self.geometry, self.by_name = geometry, by_name
        w, h = scene.width, scene.height
        self.depth = composite_kind == "composite_sort_last"
        if self.depth:
            self.rects: list[Rect] = [(0, 0, w, h)] * gpus
        else:
            rows = list(tile_rows or (h,))
            tops = [sum(rows[:i]) for i in range(gpus)]
            self.rects = [(0, tops[i], w, rows[i]) for i in range(gpus)]
        self.bpp = scene.color_bytes_per_pixel + (scene.depth_bytes_per_pixel if self.depth else 0)
        self.own = own_images(scene)
        self.first_into_target = _first_into_target(scene, self.own)  # it clears the target
        self.target_depth = self.depth or any(p.kind == "mesh" for p in scene.passes
                                              if p.name not in self.own)
        self.history = reads_own_output(scene.passes, len(scene.passes) - 1)  # the last pass's
        self.res: dict[str, Resource] = {}
        self.image("gpu0.frame", 0, (0, 0, w, h), 2 if self.history else 1, self.target_depth)
        self.res["gpu0.display"] = Resource("gpu0.display", 0, "image", w, h, False)

    def image(self, name: str, device: int, rect: Rect, nbuf: int, with_depth: bool | None = None) -> str:
        depth = self.depth if with_depth is None else with_depth
        self.res[name] = Resource(name, device, "image", rect[2], rect[3], depth, buffers=nbuf)
        return name

    def target_of(self, i: int) -> str:
        if i == 0:
            return "gpu0.frame"
        return self.image(f"gpu{i}.target", i, self.rects[i],
                          max(self.buffers, 2 if self.history else 1), self.target_depth)

    def buffer(self, name: str, device: int | None, rect: Rect) -> str:
        shared = (0, int(name.removeprefix("host.staging"))) if device is None else ()
        self.res[name] = Resource(name, device, "buffer", bytes=rect[2] * rect[3] * self.bpp,
                                  buffers=self.buffers, host_visible=True, shared_by=shared)
        return name

    def bind(self, task: Task) -> Task:
        if isinstance(task, PassTask) and task.step == "render":
            return self.render(task)
        if isinstance(task, PassTask) and task.step == "composite":
            return self.composite(task)
        if isinstance(task, PassTask) and task.step == "present":
            return dataclasses.replace(task, reads=("gpu0.frame",), writes=("gpu0.display",))
        if isinstance(task, CopyTask) and task.path == "d2h":
            return self.download(task)
        if isinstance(task, HostCopyTask):
            i = _source_gpu(task, self.by_name)
            return dataclasses.replace(task, src=f"gpu{i}.staging",
                                       dst=self.buffer(f"gpu0.staging{i}", 0, self.rects[i]))
        if isinstance(task, CopyTask) and task.path == "h2d":
            i = _source_gpu(task, self.by_name)
            src = f"gpu0.staging{i}" if self.host_copy else f"host.staging{i}"
            return dataclasses.replace(task, src=src, dst=f"gpu0.input{i}")
        return task

    def render(self, task: PassTask) -> Task:
        """A GPU's pass into its target (or an image of its own), on its tile or geometry share."""
        scene, i = self.scene, task.queue.device
        index = _pass_index(task, scene, i)
        spec = scene.passes[index]
        target, origin = self.target_of(i), ((0, 0) if i == 0 else self.rects[i][:2])
        if spec.name in self.own:
            target, origin = self.image(f"gpu{i}.pass.{spec.name}", i, self.rects[i],
                                        2 if reads_own_output(scene.passes, index) else 1,
                                        spec.kind == "mesh"), self.rects[i][:2]
        part = self.geometry[i] if self.geometry else (i, i + 1, self.gpus)
        params = _render_params(spec, scene, self.rects[i], origin, part, self.depth)
        params["clear"] = spec.name in self.own or index == self.first_into_target
        reads, extra = read_params(*filter_reads(scene.passes, index, lambda n: (
            f"gpu{i}.pass.{n}" if n in self.own else self.target_of(i))))
        params.update(extra)
        return dataclasses.replace(task, reads=reads, writes=(target,), params=MappingProxyType(params))

    def composite(self, task: PassTask) -> Task:
        """The primary draws every uploaded contribution into its frame."""
        ins = tuple(f"gpu0.input{i}" for i in range(1, self.gpus))
        for i in range(1, self.gpus):
            self.image(ins[i - 1], 0, self.rects[i], self.buffers)
        return dataclasses.replace(task, reads=ins, writes=("gpu0.frame",), params=MappingProxyType(
            {"inputs": tuple(self.rects[1:]), "frame": (self.scene.width, self.scene.height),
             "depth": self.depth}))

    def download(self, task: CopyTask) -> Task:
        """A secondary's target read back into its staging buffer (or the shared host one)."""
        i = task.queue.device
        dst = self.buffer(f"gpu{i}.staging" if self.host_copy else f"host.staging{i}",
                          i if self.host_copy else None, self.rects[i])
        colour_only = {"depth": False} if self.target_depth and not self.depth else {}
        return dataclasses.replace(task, src=f"gpu{i}.target", dst=dst,
                                   params=MappingProxyType({**task.params, **colour_only}))


def _source_gpu(task: Task, by_name: dict[str, Task]) -> int:
    """The secondary whose contribution a host copy or upload carries: follow the task's first
    dependency (the step before it in the same frame) back to that secondary's download."""
    while not (isinstance(task, CopyTask) and task.path == "d2h"):
        task = by_name[task.deps[0].task]
    return task.queue.device


def own_images(scene: Scene) -> set[str]:
    """The passes that render into an image of their own: those a later filter samples (the
    last pass renders into the target, which a filter of its own previous output reads)."""
    sampled: set[str] = set()
    for index, spec in enumerate(scene.passes):
        if spec.kind == "filter":
            found = filter_sources(scene.passes, index)
            sampled.update(found if not isinstance(found, str) else ())
    sampled.discard(scene.passes[-1].name)
    return sampled


def _first_into_target(scene: Scene, own: set[str]) -> int:
    """The index of the first pass drawn into the target (it clears it)."""
    return next(k for k, p in enumerate(scene.passes) if p.name not in own)


def _pass_index(task: PassTask, scene: Scene, gpu: int) -> int:
    """The scene pass a render task of GPU `gpu` draws."""
    return next(k for k, s in enumerate(scene.passes)
                if task.name in (f"render{gpu}", f"render{gpu}.{s.name}"))


def _render_params(spec: PassSpec, scene: Scene, rect: Rect, origin: tuple[int, int],
                   part: tuple[int, int, int], depth: bool) -> dict[str, Any]:
    """Tile rectangle (frame pixels), the target's origin in the frame, and the pass's knobs;
    sort-last GPU i draws triangles [first, first + count) of the scene's mesh: units
    [begin, end) of `part` = (begin, end, units)."""
    params: dict[str, Any] = {"rect": rect, "origin": origin, "frame": (scene.width, scene.height),
                              "depth": depth, **{k: v for k, v in spec.params.items()}, **spec.options}
    if "triangles" in spec.params:
        total = int(spec.params["triangles"])
        begin, end, units = part
        first = total * begin // units if depth else 0
        params.update(triangles=total, first=first,
                      count=(total * end // units if depth else total) - first)
    if "iterations" in spec.params:
        params["iterations"] = int(spec.params["iterations"])
    params.update(simulated_only(spec))
    return params
