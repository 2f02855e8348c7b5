"""The five-step sort-first / sort-last pipeline of explicit multi-GPU rendering on Vulkan.

Per frame: (1) every GPU renders its contribution; (2) each secondary copies it to a host
staging buffer; (3) a host-to-host copy moves it to the primary's staging buffer (skipped when
both devices import one host allocation, VK_EXT_external_memory_host); (4) the primary uploads
it; (5) the primary composites, then presents. Contributions and staging buffers are
multi-buffered (`buffers`, default 2), and at most `frames_in_flight` frames are submitted
ahead of the last present.
"""
from __future__ import annotations

from types import MappingProxyType

from .. import limits as L
from ..costs import CostModel, pass_work
from ..geometry import Placement
from ..errors import InputError
from ..profile import HardwareProfile
from ..scene import PassSpec, Scene
from ..tasks import CopyTask, Dep, HostCopyTask, PassTask, QueueRef, Task
from .base import (Footprint, FrameProgram, Option, ScheduleConfig, chain_passes, even_split,
                   present_task, present_work, queue_or_graphics, register)
from .five_step_io import bind_io

OPTIONS = {
    "host_copy": Option(bool, True, "step 3: copy between the two staging buffers on host "
                                    "threads (false: one shared host allocation)"),
    "buffers": Option(int, 2, "contribution and staging buffers per secondary", minimum=1,
                      maximum=L.MAX_BUFFERS, why=L.WHY_ALLOC),
}
SORT_FIRST_OPTIONS = {
    **OPTIONS,
    "tile_rows": Option(list, (), "sort-first: tile height per GPU, top to bottom (sum = scene "
                        "height); empty = equal tiles, the last GPU takes the remainder"),
    "balance": Option(bool, False, "sort-first: size the tiles from the GPUs' pass costs so "
                      "that every graphics queue carries the same load per frame (the primary's "
                      "includes compositing and present); overrides tile_rows"),
}


def tile_rows(height: int, gpus: int) -> list[int]:
    """Sort-first tile heights: equal, the last GPU takes the remainder."""
    return even_split(height, gpus)


@register("sort_first", "Five-step sort-first (split-frame) pipeline: horizontal tiles, colour only",
          SORT_FIRST_OPTIONS)
def build_sort_first(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    rows = _sort_first_rows(cfg, scene, profile)
    pixels = [scene.width * r for r in rows]
    contribution = [p * scene.color_bytes_per_pixel for p in pixels]
    composite = _composite("composite_sort_first", cfg.gpus - 1, sum(pixels[1:]))
    frame = (scene.width, scene.height)
    places = [Placement(frame, (0, sum(rows[:i]), scene.width, r)) for i, r in enumerate(rows)]
    return _build(cfg, scene, profile, pixels, [1.0] * cfg.gpus, contribution, composite,
                  {"tile_rows": tuple(rows), "balanced": bool(cfg.opt("balance"))}, places)


def _sort_first_rows(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> list[int]:
    """Tile heights: balanced from costs, as given per GPU, or equal."""
    if cfg.opt("balance"):
        return balanced_rows(scene, profile, cfg.gpus)
    given = list(cfg.opt("tile_rows"))
    if not given:
        return tile_rows(scene.height, cfg.gpus)
    if len(given) != cfg.gpus or not all(isinstance(r, int) and not isinstance(r, bool) and r >= 0
                                         for r in given) or sum(given) != scene.height:
        raise InputError(f"expected {cfg.gpus} non-negative integers summing to the scene height "
                         f"{scene.height}, got {given!r}", field="schedule.tile_rows")
    return given


def _graphics_load(scene: Scene, costs: CostModel, gpu: int, rows: int, n: int) -> int:
    """ns of work one frame puts on `gpu`'s graphics queue when its tile has `rows` rows."""
    px = scene.width * rows
    load = sum(costs.pass_ns(gpu, s.kind, pass_work(s, px)) for s in scene.passes)
    if gpu == 0 and n > 1:
        comp = _composite("composite_sort_first", n - 1, scene.width * (scene.height - rows))
        load += costs.pass_ns(0, comp.kind, pass_work(comp, comp.param("pixels")))
        load += costs.pass_ns(0, "present", present_work(scene.pixels))
    return load


def balanced_rows(scene: Scene, profile: HardwareProfile, n: int) -> list[int]:
    """Tile heights that minimise the largest per-frame graphics load (the thesis's proposed
    load balancing, from the GPUs' costs): the smallest time T for which the rows each GPU
    can render within T cover the screen, found by bisection on integer ns. Copies run on
    other queues and overlap the next frame, so they do not enter the balance."""
    costs, h = CostModel(profile), scene.height

    def rows_within(gpu: int, t: int) -> int:
        lo, hi = -1, h  # largest r in [0, h] with load <= t, or -1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if _graphics_load(scene, costs, gpu, mid, n) <= t:
                lo = mid
            else:
                hi = mid - 1
        return lo

    lo, hi = 0, max(_graphics_load(scene, costs, g, h, n) for g in range(n))
    while lo < hi:
        mid = (lo + hi) // 2
        if sum(max(rows_within(g, mid), 0) for g in range(n)) >= h:
            hi = mid
        else:
            lo = mid + 1
    rows = [max(rows_within(g, lo), 0) for g in range(n)]
    for g in reversed(range(n)):  # trim the excess, last GPUs first
        cut = min(rows[g], sum(rows) - h)
        rows[g] -= cut
    return rows


@register("sort_last", "Five-step sort-last pipeline: geometry split evenly, full-frame colour + depth",
          OPTIONS)
def build_sort_last(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    n = cfg.gpus
    per_gpu = scene.color_bytes + scene.depth_bytes
    composite = _composite("composite_sort_last", n - 1, (n - 1) * scene.pixels)
    places = [Placement((scene.width, scene.height), share=(i, n)) for i in range(n)]
    return _build(cfg, scene, profile, [scene.pixels] * n, [1.0 / n] * n, [per_gpu] * n,
                  composite, {"geometry_share": 1.0 / n}, places)


def _composite(kind: str, inputs: int, pixels: int) -> PassSpec:
    return PassSpec("composite", kind, MappingProxyType({"inputs": inputs, "pixels": pixels}))


def _build(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile, pixels: list[int],
           shares: list[float], contribution: list[int], composite: PassSpec,
           record: dict, places: list[Placement]) -> FrameProgram:
    n, buffers, fif = cfg.gpus, cfg.opt("buffers"), cfg.frames_in_flight
    host_copy = cfg.opt("host_copy")
    tasks: list[Task] = []
    last_render: list[str] = []
    for i in range(n):
        tasks.extend(_renders(i, scene, pixels[i], shares[i], places[i], fif, buffers))
        last_render.append(tasks[-1].name)
    uploads = []
    h2d_queue = queue_or_graphics(profile, 0, "transfer")
    for i in range(1, n):
        d2h_queue = queue_or_graphics(profile, i, "transfer")
        staged = f"d2h{i}"
        tasks.append(CopyTask(staged, "d2h", d2h_queue, "d2h", contribution[i],
                              (Dep(last_render[i]), Dep(f"{'host_copy' if host_copy else 'h2d'}{i}", -buffers))))
        if host_copy:
            tasks.append(HostCopyTask(f"host_copy{i}", "host_copy", contribution[i],
                                      (Dep(staged), Dep(f"h2d{i}", -buffers))))
            staged = f"host_copy{i}"
        tasks.append(CopyTask(f"h2d{i}", "h2d", h2d_queue, "h2d", contribution[i],
                              (Dep(staged), Dep("composite", -buffers))))
        uploads.append(f"h2d{i}")
    primary = QueueRef(0, "graphics")
    if n > 1:
        work = pass_work(composite, composite.param("pixels"))
        tasks.append(PassTask("composite", "composite", primary, composite.kind, MappingProxyType(work),
                              tuple(Dep(t) for t in [last_render[0], *uploads])))
    before_present = "composite" if n > 1 else last_render[0]
    tasks.append(present_task(primary, scene.pixels, before_present))
    record.update(buffers=buffers, host_copy=host_copy,
                  contribution_bytes_per_frame=sum(contribution[1:]))
    tasks, resources = bind_io(tasks, scene, n, composite.kind, record.get("tile_rows"),
                               buffers, host_copy)
    return FrameProgram(cfg.name, n, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), resources=resources,
                        footprints=_footprints(scene, pixels, shares, contribution, buffers))


def _footprints(scene: Scene, pixels: list[int], shares: list[float], contribution: list[int],
                buffers: int) -> tuple[Footprint, ...]:
    """The primary holds its target, the frame's colour and `buffers` receive buffers per
    secondary; each secondary `buffers` targets (colour + depth) of its contribution."""
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    targets = [p * bpp for p in pixels]
    primary = Footprint(0, shares[0], targets[0] + scene.color_bytes, buffers * sum(contribution[1:]))
    return (primary,) + tuple(Footprint(i, shares[i], buffers * targets[i], 0)
                              for i in range(1, len(pixels)))


def _renders(gpu: int, scene: Scene, pixels: int, share: float, place: Placement, fif: int,
             buffers: int) -> list[PassTask]:
    """The scene's passes on one GPU's graphics queue; the first waits for frame f-fif's
    present (frames in flight) and, on a secondary, for its contribution buffer to be free."""
    first = (Dep("present", -fif),) + ((Dep(f"d2h{gpu}", -buffers),) if gpu > 0 else ())
    single = len(scene.passes) == 1
    return chain_passes(scene.passes, QueueRef(gpu, "graphics"), first, pixels,
                        lambda spec: f"render{gpu}" if single else f"render{gpu}.{spec.name}",
                        share, place=place)
