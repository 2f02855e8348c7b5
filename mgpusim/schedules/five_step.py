"""The five-step sort-first / sort-last pipeline of explicit multi-GPU rendering on Vulkan.

Per frame: (1) every GPU renders its contribution; (2) each secondary copies it to a host
staging buffer; (3) a host-to-host copy moves it to the primary's staging buffer (skipped when
both devices import one host allocation, VK_EXT_external_memory_host); (4) the primary uploads
it; (5) the primary composites, then presents. Contributions and staging buffers are
multi-buffered (`buffers`, default 2), and at most `frames_in_flight` frames are submitted
ahead of the last present.
"""
from __future__ import annotations

import math
from dataclasses import replace
from fractions import Fraction
from types import MappingProxyType
from typing import Sequence

from mgpusim.model import limits as L
from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import Placement, even_split
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import CopyTask, Dep, HostCopyTask, PassTask, QueueRef, Task
from mgpusim.model.work_terms import PLACED_TERMS, pass_work
from mgpusim.schedules.base import Footprint, FrameProgram, chain_passes, present_task, present_work, queue_or_graphics
from mgpusim.schedules.five_step_io import bind_io
from mgpusim.schedules.host_loop import as_built
from mgpusim.schedules.registry import Option, ScheduleConfig, register

#: `pipelining` modes, from most to least overlap (see OPTIONS).
PIPELINING = ("full", "secondary_wait", "lockstep")
#: `host_work` modes (see OPTIONS).
HOST_WORK = ("overlapped", "as_built")

OPTIONS = {
    "host_copy": Option(bool, True, "step 3: copy between the two staging buffers on host "
                                    "threads (false: one shared host allocation)"),
    "buffers": Option(int, 2, "contribution and staging buffers per secondary", minimum=1,
                      maximum=L.MAX_BUFFERS, why=L.WHY_ALLOC),
    "pipelining": Option(str, "full", "how much of the five steps overlaps across frames: "
                         "'full' (every step, limited only by buffers and frames in flight), "
                         "'secondary_wait' (a secondary renders its next frame only after its "
                         "download ended: the reference code's waitIdle), 'lockstep' (no GPU "
                         "starts a frame before the previous one was presented)",
                         choices=PIPELINING),
    "host_work": Option(str, "overlapped", "the host's part of each frame: 'overlapped' (the "
                        "host only copies; every step is submitted as soon as its inputs are "
                        "ready) or 'as_built' (the thesis's reference code: threads started and "
                        "joined every frame, each submit followed by a wait for the queue to be "
                        "idle, the host copy read from uncached staging memory on every hardware "
                        "thread, every contribution composited, a barrier per frame; "
                        "mgpusim/schedules/host_loop.py)", choices=HOST_WORK),
    "update_gap_ns": Option(int, 0, "with host_work = 'as_built': the window's idle time between "
                            "a present and the next frame (Qt's update request: "
                            "QT_QPA_UPDATE_IDLE_TIME, 5 ms by default in the reference renderer's "
                            "window); 0 = the next frame starts at once", minimum=0,
                            maximum=L.MAX_TASK_NS, why=L.WHY_TIME),
}
SORT_FIRST_OPTIONS = {
    **OPTIONS,
    "tile_rows": Option(list, (), "sort-first: tile height per GPU, top to bottom (sum = scene "
                        "height); empty = equal tiles, the last GPU takes the remainder"),
    "balance": Option(bool, False, "sort-first: size the tiles from the GPUs' pass costs so "
                      "that every graphics queue carries the same load per frame (the primary's "
                      "includes compositing and present); overrides tile_rows"),
    "tiles": Option(int, 0, "sort-first: the screen in this many horizontal strips of equal "
                    "height (the last takes the remainder), strip k on GPU k mod N (interleaved "
                    "small tiles; with balance, strips in proportion to the balanced tile "
                    "heights); 0 = one tile per GPU", minimum=0, maximum=L.MAX_SIDE,
                    why=L.WHY_IMAGE),
}
SORT_LAST_OPTIONS = {
    **OPTIONS,
    "object_counts": Option(list, (), "sort-last: whole objects per GPU (sum = scene.objects); "
                            "empty = as even as whole objects allow, the first GPUs one more"),
}


def tile_rows(height: int, gpus: int) -> list[int]:
    """Sort-first tile heights: equal, the last GPU takes the remainder."""
    return even_split(height, gpus)


@register("sort_first", "Five-step sort-first (split-frame) pipeline: horizontal tiles, colour only",
          SORT_FIRST_OPTIONS)
def build_sort_first(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    if cfg.opt("tiles") and cfg.opt("tiles") != cfg.gpus:
        return _build_strips(cfg, scene, profile)
    rows = _sort_first_rows(cfg, scene, profile)
    pixels = [scene.width * r for r in rows]
    contribution = [p * scene.color_bytes_per_pixel for p in pixels]
    composite = (_composite("composite_sort_first", cfg.gpus, sum(pixels)) if _composites_all(cfg)
                 else _composite("composite_sort_first", cfg.gpus - 1, sum(pixels[1:])))
    frame = (scene.width, scene.height)
    places = [Placement(frame, (0, sum(rows[:i]), scene.width, r)) for i, r in enumerate(rows)]
    return _build(cfg, scene, profile, pixels, [1.0] * cfg.gpus, contribution, composite,
                  {"tile_rows": tuple(rows), "balanced": bool(cfg.opt("balance"))}, places)


def strip_owners(tiles: int, counts: list[int]) -> list[int]:
    """The GPU of each of `tiles` strips, `counts[g]` strips for GPU g, interleaved as evenly
    as the counts allow (smooth weighted round robin; equal counts: strip k on GPU k mod N)."""
    total, current, owners = sum(counts), [0] * len(counts), []
    for _ in range(tiles):
        current = [c + w for c, w in zip(current, counts)]
        g = max(range(len(counts)), key=lambda i: (current[i], -i))
        current[g] -= total
        owners.append(g)
    return owners


def _strip_counts(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> list[int]:
    """Strips per GPU: round robin (k mod N), or with `balance` in proportion to the balanced
    tile heights (largest remainder), so a slower GPU gets fewer of them."""
    n, tiles = cfg.gpus, cfg.opt("tiles")
    if not cfg.opt("balance"):
        return [len(range(g, tiles, n)) for g in range(n)]
    exact = [Fraction(r * tiles, scene.height) for r in balanced_rows(scene, profile, n)]
    counts = [math.floor(e) for e in exact]
    for g in sorted(range(n), key=lambda g: (counts[g] - exact[g], g))[:tiles - sum(counts)]:
        counts[g] += 1
    return counts


def _build_strips(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    """Sort-first over `tiles` interleaved strips: each GPU renders its strips in one pass
    (scissored to them), a secondary's strips cross as one copy, and the composite draws one
    rectangle per strip from a secondary (its `input` term counts the strips)."""
    n, tiles = cfg.gpus, cfg.opt("tiles")
    if cfg.opt("tile_rows"):
        raise InputError(f"tiles = {tiles} places interleaved strips; it cannot be combined "
                         "with tile_rows", field="schedule.tiles")
    if tiles < n or tiles > scene.height:
        raise InputError(f"expected 0 or {n}..{scene.height} strips (at least one per GPU, at "
                         f"most one per row), got {tiles}", field="schedule.tiles")
    strips = even_split(scene.height, tiles)
    owners = strip_owners(tiles, _strip_counts(cfg, scene, profile))
    rows = [sum(h for h, g in zip(strips, owners) if g == gpu) for gpu in range(n)]
    pixels = [scene.width * r for r in rows]
    contribution = [p * scene.color_bytes_per_pixel for p in pixels]
    remote = sum(1 for g in owners if g)
    composite = _composite("composite_sort_first", remote, sum(pixels[1:]))
    record = {"tile_rows": tuple(rows), "strip_rows": tuple(strips), "tiles": tiles,
              "strip_gpus": tuple(owners), "balanced": bool(cfg.opt("balance"))}
    why = (f"the Vulkan runner renders one tile per GPU; schedule.tiles = {tiles} interleaved "
           "strips are simulated only")
    frame = (scene.width, scene.height)
    tops = [sum(strips[:k]) for k in range(tiles)]
    places = [tuple(Placement(frame, (0, tops[k], scene.width, strips[k]))
                    for k in range(tiles) if owners[k] == g) for g in range(n)]
    return _build(cfg, scene, profile, pixels, [1.0] * n, contribution, composite, record,
                  places, unsupported=why)


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
    known: dict[tuple[int, int], int] = {}  # (gpu, rows) -> load: the bisections revisit rows
    within: dict[tuple[int, int], int] = {}  # (gpu, time) -> rows
    alike = _alike_gpus(profile, n)

    def load(gpu: int, rows: int) -> int:
        gpu = alike[gpu]
        if (gpu, rows) not in known:
            known[gpu, rows] = _graphics_load(scene, costs, gpu, rows, n)
        return known[gpu, rows]

    def rows_within(gpu: int, t: int) -> int:
        gpu = alike[gpu]
        if (gpu, t) in within:
            return within[gpu, t]
        lo, hi = -1, h  # largest r in [0, h] with load <= t, or -1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if load(gpu, mid) <= t:
                lo = mid
            else:
                hi = mid - 1
        within[gpu, t] = lo
        return lo

    lo, hi = 0, max(load(g, h) for g in range(n))
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


def _alike_gpus(profile: HardwareProfile, n: int) -> list[int]:
    """For each of the first `n` GPUs, the first GPU from GPU 1 on with the same profile (GPU 0
    itself: it composites). Why: GPUs alike have one load for each tile height, so the
    balance's bisections need it once; the first is the one whose load the search would
    have computed (and failed on) first."""
    out = [0]
    for g in range(1, n):
        out.append(next(k for k in range(1, g + 1) if profile.gpus[k] == profile.gpus[g]))
    return out


@register("sort_last", "Five-step sort-last pipeline: geometry split evenly (or in whole objects), "
          "full-frame colour + depth", SORT_LAST_OPTIONS)
def build_sort_last(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    n = cfg.gpus
    per_gpu = scene.color_bytes + scene.depth_bytes
    layers = n if _composites_all(cfg) else n - 1
    composite = _composite("composite_sort_last", layers, layers * scene.pixels)
    frame = (scene.width, scene.height)
    counts = object_counts(cfg, scene)
    if counts is None:
        shares, bounds = [1.0 / n] * n, [(i, i + 1, n) for i in range(n)]
        record: dict = {"geometry_share": 1.0 / n}
    else:
        shares = [c / scene.objects for c in counts]
        bounds = [(sum(counts[:i]), sum(counts[:i + 1]), scene.objects) for i in range(n)]
        record = {"geometry_share": max(shares), "object_counts": tuple(counts)}
    places = [Placement(frame, share=(b, units), span=e - b) for b, e, units in bounds]
    return _build(cfg, scene, profile, [scene.pixels] * n, shares, [per_gpu] * n,
                  composite, record, places, geometry=bounds)


def object_counts(cfg: ScheduleConfig, scene: Scene) -> list[int] | None:
    """Whole objects per GPU (None: the geometry splits evenly into fractions): as given, or
    as even as whole objects allow with the first GPUs taking one more (8 on 3 GPUs: 3/3/2)."""
    given, n = list(cfg.opt("object_counts")), cfg.gpus
    if not scene.objects:
        if given:
            raise InputError("object_counts needs scene.objects (the whole objects to share)",
                             field="schedule.object_counts")
        return None
    if not given:
        base, extra = divmod(scene.objects, n)
        return [base + (1 if i < extra else 0) for i in range(n)]
    if len(given) != n or not all(isinstance(c, int) and not isinstance(c, bool) and c >= 0
                                  for c in given) or sum(given) != scene.objects:
        raise InputError(f"expected {n} non-negative integers summing to scene.objects = "
                         f"{scene.objects}, got {given!r}", field="schedule.object_counts")
    return given


def _composites_all(cfg: ScheduleConfig) -> bool:
    """The reference code renders the primary's part offscreen too and composites every
    GPU's contribution (as built); otherwise the primary renders into the frame and the
    composite draws only the secondaries'."""
    return cfg.opt("host_work") == "as_built" and cfg.gpus > 1


def _composite(kind: str, inputs: int, pixels: int) -> PassSpec:
    return PassSpec("composite", kind, MappingProxyType({"inputs": inputs, "pixels": pixels}))


def _build(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile, pixels: list[int],
           shares: list[float], contribution: list[int], composite: PassSpec,
           record: dict, places: Sequence[Placement | tuple[Placement, ...]], *,
           geometry: list[tuple[int, int, int]] | None = None,
           unsupported: str | None = None) -> FrameProgram:
    """The five steps for every GPU: `pixels`, geometry `shares`, `places` (where it draws)
    and `contribution` bytes per GPU; `geometry` = per GPU (first, end, of units) of the mesh
    it draws (the runner's triangle range); `unsupported`: why the Vulkan runner cannot run
    this program."""
    n, buffers, fif = cfg.gpus, cfg.opt("buffers"), cfg.frames_in_flight
    host_copy = cfg.opt("host_copy")
    tasks: list[Task] = []
    last_render: list[str] = []
    for i in range(n):
        tasks.extend(_renders(i, scene, pixels[i], shares[i], places[i], fif, buffers,
                              cfg.opt("pipelining")))
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
    record.update(buffers=buffers, host_copy=host_copy, pipelining=cfg.opt("pipelining"),
                  contribution_bytes_per_frame=sum(contribution[1:]))
    tasks, resources = bind_io(tasks, scene, n, composite.kind, record.get("tile_rows"),
                               buffers, host_copy, geometry)
    if cfg.opt("update_gap_ns") and cfg.opt("host_work") != "as_built":
        raise InputError("update_gap_ns is the reference renderer's window loop: it needs "
                         "host_work = 'as_built'", field="schedule.update_gap_ns")
    if cfg.opt("host_work") == "as_built":
        _check_as_built(cfg)
        tasks = as_built(tasks, n, last_render, depth=composite.kind == "composite_sort_last",
                         update_gap_ns=cfg.opt("update_gap_ns"))
        record.update(host_work="as_built")
    if unsupported:
        tasks = [replace(t, params=MappingProxyType({**t.params, "unsupported": unsupported}))
                 if isinstance(t, PassTask) and t.step == "render" else t for t in tasks]
    return FrameProgram(cfg.name, n, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), resources=resources,
                        footprints=_footprints(scene, pixels, shares, contribution, buffers,
                                               geometry))


def _check_as_built(cfg: ScheduleConfig) -> None:
    """The reference code's loop has its own overlap (a barrier per frame) and one tile per GPU."""
    if cfg.opt("pipelining") != "full":
        raise InputError(f"host_work = 'as_built' runs the reference code's own frame loop (a "
                         f"barrier per frame); it cannot be combined with pipelining = "
                         f"{cfg.opt('pipelining')!r}", field="schedule.pipelining")
    if cfg.options.get("tiles") not in (None, 0, cfg.gpus):
        raise InputError("host_work = 'as_built' renders one tile per GPU, as the reference code "
                         "does; it cannot be combined with interleaved strips", field="schedule.tiles")


def _footprints(scene: Scene, pixels: list[int], shares: list[float], contribution: list[int],
                buffers: int, geometry: list[tuple[int, int, int]] | None = None
                ) -> tuple[Footprint, ...]:
    """The primary holds its target, the frame's colour and `buffers` receive buffers per
    secondary; each secondary `buffers` targets (colour + depth) of its contribution. With
    sections, a GPU holds whole sections: those of its objects (sort-last), else all."""
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    targets = [p * bpp for p in pixels]
    primary = Footprint(0, shares[0], targets[0] + scene.color_bytes,
                        buffers * sum(contribution[1:]), **_held(scene, 0, geometry))
    return (primary,) + tuple(Footprint(i, shares[i], buffers * targets[i], 0,
                                        **_held(scene, i, geometry))
                              for i in range(1, len(pixels)))


def _held(scene: Scene, gpu: int, geometry: list[tuple[int, int, int]] | None) -> dict:
    """The sections GPU `gpu` holds whole, and their bytes ({} without sections)."""
    if not scene.sections:
        return {}
    begin, end = (geometry[gpu][0], geometry[gpu][1]) if geometry else (0, len(scene.sections))
    held = scene.sections[begin:end]
    return {"sections": tuple(s.name for s in held), "section_bytes": sum(s.bytes for s in held)}


def _renders(gpu: int, scene: Scene, pixels: int, share: float,
             place: Placement | tuple[Placement, ...], fif: int, buffers: int,
             pipelining: str = "full") -> list[PassTask]:
    """The scene's passes on one GPU's graphics queue; the first waits for frame f-fif's
    present (frames in flight) and, on a secondary, for its contribution buffer to be free.
    Less `pipelining` adds waits: 'secondary_wait' a secondary's download of the previous
    frame (its host thread idles until then before submitting more), 'lockstep' the previous
    frame's present on every GPU. A GPU drawing several strips (`place` a tuple) has the
    placed work terms of each strip, summed (a mesh is set up once per strip)."""
    first = (Dep("present", -fif),) + ((Dep(f"d2h{gpu}", -buffers),) if gpu > 0 else ())
    if pipelining != "full" and gpu > 0 and buffers > 1:
        first += (Dep(f"d2h{gpu}", -1),)
    if pipelining == "lockstep" and fif > 1:
        first += (Dep("present", -1),)
    single = len(scene.passes) == 1
    strips = place if isinstance(place, tuple) else None
    tasks = chain_passes(scene.passes, QueueRef(gpu, "graphics"), first, pixels,
                         lambda spec: f"render{gpu}" if single else f"render{gpu}.{spec.name}",
                         share, place=None if isinstance(place, tuple) else place)
    if strips is None:
        return tasks
    return [replace(t, work=MappingProxyType({**t.work, **_placed_sum(spec, share, strips)}))
            for t, spec in zip(tasks, scene.passes)]


def _placed_sum(spec: PassSpec, share: float, places: tuple[Placement, ...]) -> dict[str, float]:
    """A pass's placed work terms (a mesh's visible triangles, ...) summed over strips."""
    total: dict[str, float] = {}
    for place in places:
        for term in PLACED_TERMS.get(spec.kind, ()):
            total[term] = total.get(term, 0.0) + pass_work(spec, 0, share, place).get(term, 0.0)
    return total
