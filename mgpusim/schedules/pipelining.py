"""Frame pipelining: a frame's first passes on GPU 1, the rest on GPU 0.

The scene's passes [0, split_at) run on GPU 1; their outputs (each pass's `output_bytes`)
cross to GPU 0 (through host memory, or over a peer link), where the remaining passes run and
the frame is presented. GPU 1 starts frame f+1 while GPU 0 finishes frame f, so the GPUs and
copy engines form a pipeline: copies cost latency, not frame rate, unless they take longer
than the work. Copies can be issued per pass (as soon as each output is ready) and split into
`chunks` pieces, so the destination's upload of one piece overlaps the download of the next
and the rest of the frame's work. Intermediate buffers are multi-buffered (`buffers`).
"""
from __future__ import annotations

import functools
from collections import defaultdict
from dataclasses import replace
from types import MappingProxyType

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import Dep, PassTask, QueueRef, Resource, Task
from mgpusim.schedules.base import Footprint, FrameProgram, chain_passes, present_task
from mgpusim.schedules.binding import (
    COLOUR_PIXEL_BYTES,
    DEPTH_PIXEL_BYTES,
    Bindings,
    bind_crossing,
    chunk_bytes,
    row_chunks,
)
from mgpusim.schedules.crossing import COPY_OPTIONS, Route, cross
from mgpusim.schedules.pass_io import bind_full_frame, filter_reads, filter_sources, pass_image, reads_own_output
from mgpusim.schedules.registry import Option, ScheduleConfig, register

OPTIONS = {
    **COPY_OPTIONS,
    "split_at": Option(int, 1, "passes [0, split_at) run on GPU 1, the rest on GPU 0 "
                       "(0 = everything on GPU 0)", minimum=0),
    "copy_granularity": Option(str, "pass", "'pass': copy each pass's output when that pass "
                               "ends; 'frame': one copy after GPU 1's last pass",
                               choices=("pass", "frame")),
    "chunks": Option(int, 1, "split every copy into this many equal pieces", minimum=1,
                     maximum=L.MAX_CHUNKS, why=L.WHY_ALLOC),
    "buffers": Option(int, 2, "copies of the intermediate buffers on each GPU", minimum=1,
                      maximum=L.MAX_BUFFERS, why=L.WHY_ALLOC),
    "consumer_waits": Option(str, "all", "'all': GPU 0's first pass waits for every piece "
                             "that crosses; 'reads': each GPU 0 pass waits only for the pieces "
                             "of the GPU 1 outputs it reads (`reads`), so a piece's arrival "
                             "overlaps GPU 0's other work of the same frame",
                             choices=("all", "reads")),
    "reads": Option(dict, {}, "with consumer_waits = 'reads': GPU 0 pass -> the GPU 1 passes "
                    "whose outputs it reads (a filter reads its inputs unless listed here)"),
    "producer_chunks": Option(bool, False, "GPU 1's passes render their output in `chunks` "
                              "pieces (a sub-pass each, with its own fixed cost), and a piece's "
                              "copy leaves as soon as its sub-pass ended; false: a copy leaves "
                              "after its whole pass"),
    "consumer_chunks": Option(bool, False, "with consumer_waits = 'reads': a GPU 0 pass that "
                              "reads GPU 1 outputs runs in `chunks` pieces (a sub-pass each), "
                              "piece c waiting only for chunk c of what it reads"),
}


@register("pipelining", "Frame pipelining on 2 GPUs: first passes on GPU 1, the rest and present on GPU 0",
          OPTIONS)
def build_pipelining(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile) -> FrameProgram:
    split = _split(cfg, scene)
    route = Route.from_options(cfg.opt)
    first, rest = scene.passes[:split], scene.passes[split:]
    tasks: list[Task] = []
    arrivals: list[tuple[str, str]] = []
    buffers, fif = cfg.opt("buffers"), cfg.frames_in_flight
    readers = _readers(cfg, scene, split)
    if first:
        renders = _passes(1, first, scene, (Dep("present", -fif),))
        if _producer_split(cfg):
            renders = _split_renders(renders, cfg.opt("chunks"))
        copies, arrivals = _copies(cfg, scene, profile, route, first, readers)
        # GPU 1 may overwrite its outputs once the copies of frame f-buffers have read them
        reads = tuple(Dep(c.name, -buffers) for c in copies if c.step in ("d2h", "p2p"))
        renders[0] = _with_deps(renders[0], reads)
        tasks.extend(_interleave(renders, copies))
    if readers is None:  # 'all': GPU 0's first pass waits for everything
        gate = (Dep("present", -fif),) + tuple(Dep(a) for _, a in arrivals)
        tasks.extend(_passes(0, rest, scene, gate))
        after = tuple(Dep(a) for _, a in arrivals[-1:]) if not rest else ()
    else:
        pieces = cfg.opt("chunks") if _consumer_split(cfg) else 1
        tasks.extend(_reading_passes(rest, scene, fif, readers, arrivals, pieces))
        unread = {g for g, _ in arrivals} - {g for gs in readers.values() for g in gs}
        after = tuple(Dep(a) for g, a in arrivals if g in unread)
    last = tasks[-1].name if rest else None
    present = present_task(QueueRef(0, "graphics"), scene.pixels, last or after[-1].task)
    if last and after:  # pieces nobody on GPU 0 reads still arrive within the frame
        present = _with_deps(present, after)
    tasks.append(present)
    moved = sum(_output_bytes(p) for p in first)
    record = {"split_at": split, "gpu1_passes": tuple(p.name for p in first),
              "bytes_per_frame": moved, "chunks": cfg.opt("chunks"), "buffers": buffers,
              "copy_granularity": cfg.opt("copy_granularity"),
              "consumer_waits": cfg.opt("consumer_waits")}
    tasks, resources = _bind(tasks, cfg, scene, split)
    return FrameProgram(cfg.name, cfg.gpus, cfg.frames, cfg.warmup_frames, (tuple(tasks),),
                        record=MappingProxyType(record), resources=resources,
                        footprints=_footprints(scene, cfg.gpus, buffers * moved))


def _bind(tasks: list[Task], cfg: ScheduleConfig, scene: Scene,
          split: int) -> tuple[list[Task], tuple[Resource, ...]]:
    """What every task reads and writes on the Vulkan runner.

    Pass X renders into `gpu1.pass.X` (GPU 1's passes, `buffers` copies) or `gpu0.pass.X`;
    GPU 1's outputs arrive in `gpu0.in.X` (`buffers` copies), which GPU 0's filters sample in
    their place; a filter sampling its own previous output renders into two copies at least.
    A copy carries colour only, unless the pass's output_bytes also count a mesh's depth (a
    later pass never reads a mesh's depth: each renders into an image of its own). A chunk of
    a copy is a range of rows of each image it carries (the last chunk takes the rows left
    over). Present copies the last pass's image to `gpu0.display`."""
    b, buffers = Bindings(), cfg.opt("buffers")
    first = {p.name for p in scene.passes[:split]}
    staging = max(buffers, cfg.frames_in_flight)
    b.image("gpu0.display", 0, scene.width, scene.height)

    def image_of(name: str, on_gpu0: bool) -> str:
        return (f"gpu0.in.{name}" if name in first else f"gpu0.pass.{name}") if on_gpu0 \
            else f"gpu1.pass.{name}"

    for index, spec in enumerate(scene.passes):
        history = 2 if reads_own_output(scene.passes, index) else 1  # written while read
        if spec.name in first:
            pass_image(b, f"gpu1.pass.{spec.name}", 1, scene, spec, max(buffers, history))
            pass_image(b, f"gpu0.in.{spec.name}", 0, scene, spec, buffers)
        else:
            pass_image(b, f"gpu0.pass.{spec.name}", 0, scene, spec, history)
    crossed = _bind_copies(tasks, cfg, scene, split, b, staging)
    out: list[Task] = []
    for task in tasks:
        if task.name in crossed:
            out.append(crossed[task.name])
        elif isinstance(task, PassTask) and "unsupported" in task.params:
            out.append(task)  # a sub-pass of a pass rendered in pieces: simulated only
        elif isinstance(task, PassTask) and task.step == "render":
            index = next(i for i, s in enumerate(scene.passes) if task.name == f"render.{s.name}")
            spec, on_gpu0 = scene.passes[index], task.queue.device == 0
            target = image_of(spec.name, on_gpu0)
            reads = filter_reads(scene.passes, index, functools.partial(image_of, on_gpu0=on_gpu0))
            out.append(bind_full_frame(task, spec, scene, target, *reads))
        elif task.name == "present":
            assert isinstance(task, PassTask)
            out.append(replace(task, reads=(image_of(scene.passes[-1].name, True),),
                               writes=("gpu0.display",)))
        else:
            out.append(task)
    return out, b.resources()


def _bind_copies(tasks: list[Task], cfg: ScheduleConfig, scene: Scene, split: int, b: Bindings,
                 staging: int) -> dict[str, Task]:
    """The copy tasks of every piece, bound: rows of GPU 1's outputs into GPU 0's inputs (one
    output per copy, or with `copy_granularity = 'frame'` all that have output_bytes, one
    after the other through one buffer)."""
    chunks = cfg.opt("chunks")
    copied = [p.name for p in scene.passes[:split] if _output_bytes(p)]
    if cfg.opt("copy_granularity") == "frame":
        groups = [("out", tuple(copied))]
    else:
        groups = [(f"out.{p.name}", (p.name,)) for p in scene.passes[:split]]
    crossed: dict[str, Task] = {}
    missing = sorted(_needed_on_gpu0(scene, split) - set(copied))
    regions = row_chunks(scene.height, chunks)
    pieces: dict[str, list[Task]] = defaultdict(list)  # one pass over the tasks, not one per piece
    for t in tasks:
        pieces[t.name.rpartition(".")[0]].append(t)
    for prefix, names in groups:
        colour_only = not _with_depth(scene, names)
        for c in range(chunks):
            piece_name = prefix if chunks == 1 else f"{prefix}#{c}"
            piece = pieces[piece_name]
            params = dict(regions[c])
            if colour_only:
                params["depth"] = False
            if missing:
                params = {"unsupported": f"GPU 0 reads the output of pass {missing[0]!r}, but "
                          f"its output_bytes is 0: set it to the image's bytes (width x height x 4)"}
            first = names[0] if names else scene.passes[0].name
            crossed.update((t.name, t) for t in bind_crossing(
                piece, b, f"gpu1.pass.{first}", f"gpu0.in.{first}", staging=piece_name,
                buffers=staging, params=params,
                down={"images": tuple(f"gpu1.pass.{n}" for n in names)},
                up={"images": tuple(f"gpu0.in.{n}" for n in names)}))
    return crossed


def _with_depth(scene: Scene, names: tuple[str, ...]) -> bool:
    """Whether a copy of the outputs `names` carries depth too: their output_bytes are their
    images' colour and depth bytes (a mesh's image has both; the model's bytes decide)."""
    specs = [_spec(scene, n) for n in names]
    meshes = sum(s.kind == "mesh" for s in specs)
    colour_and_depth = scene.pixels * (len(specs) * COLOUR_PIXEL_BYTES
                                       + meshes * DEPTH_PIXEL_BYTES)
    return meshes > 0 and sum(_output_bytes(s) for s in specs) == colour_and_depth


def _footprints(scene: Scene, n: int, intermediate: int) -> tuple[Footprint, ...]:
    """GPU 0 holds the data set, a full target and the arriving intermediate buffers; GPU 1
    the intermediate results it renders."""
    primary = Footprint(0, 1.0, scene.color_bytes + scene.depth_bytes, intermediate)
    return (primary,) + ((Footprint(1, 1.0, intermediate, 0),) if n > 1 else ())


def _split(cfg: ScheduleConfig, scene: Scene) -> int:
    if cfg.gpus > 2:
        raise InputError(f"pipelining runs on 1 or 2 GPUs, got {cfg.gpus}", field="schedule.gpus")
    split = 0 if cfg.gpus == 1 else cfg.opt("split_at")
    if split > len(scene.passes):
        raise InputError(f"split_at = {split} but the scene has {len(scene.passes)} passes",
                         field="schedule.split_at")
    return split


def _output_bytes(spec: PassSpec) -> int:
    return int(spec.param("output_bytes"))


def _passes(gpu: int, specs: tuple[PassSpec, ...], scene: Scene, first_deps: tuple[Dep, ...]) -> list[PassTask]:
    return chain_passes(specs, QueueRef(gpu, "graphics"), first_deps, scene.pixels,
                        lambda spec: f"render.{spec.name}", place=scene.whole_frame)


def _copies(cfg: ScheduleConfig, scene: Scene, profile: HardwareProfile, route: Route,
            first: tuple[PassSpec, ...],
            readers: dict[str, tuple[str, ...]] | None) -> tuple[list[Task], list[tuple[str, str]]]:
    """The crossing tasks, and (copy group, name whose end means a piece of it arrived on
    GPU 0). A group's buffer is free again for frame f once frame f-buffers' consumer ran:
    GPU 0's first pass ('all'), else the last GPU 0 pass reading it, else the present."""
    if cfg.opt("copy_granularity") == "frame":
        groups = [("out", sum(_output_bytes(p) for p in first), f"render.{first[-1].name}")]
    else:
        groups = [(f"out.{p.name}", _output_bytes(p), f"render.{p.name}") for p in first]
    tasks: list[Task] = []
    arrivals: list[tuple[str, str]] = []
    chunks, buffers = cfg.opt("chunks"), cfg.opt("buffers")
    for prefix, nbytes, after in groups:
        consumer = _consumer(cfg, scene, prefix, readers)
        for c, size in enumerate(chunk_bytes(nbytes, scene.height, chunks)):
            name = prefix if chunks == 1 else f"{prefix}#{c}"
            ready = f"{after}#{c}" if _producer_split(cfg) else after
            reader = f"{consumer}#{c}" if _consumer_split(cfg) and consumer != "present" else consumer
            piece = cross(name, profile, 1, 0, size, (Dep(ready),), route,
                          dst_deps=(Dep(reader, -buffers),))
            tasks.extend(piece)
            arrivals.append((prefix, piece[-1].name))
    return tasks, arrivals


def _producer_split(cfg: ScheduleConfig) -> bool:
    """Whether GPU 1's passes render their output in `chunks` pieces."""
    if not cfg.opt("producer_chunks"):
        return False
    if cfg.opt("copy_granularity") == "frame":
        raise InputError("a pass's output leaves in pieces only with copy_granularity = 'pass'",
                         field="schedule.producer_chunks")
    return cfg.opt("chunks") > 1


def _consumer_split(cfg: ScheduleConfig) -> bool:
    """Whether GPU 0's reading passes run in `chunks` pieces, each after its chunk."""
    if not cfg.opt("consumer_chunks"):
        return False
    if cfg.opt("consumer_waits") != "reads" or cfg.opt("copy_granularity") == "frame":
        raise InputError("pieces of a reading pass wait for chunks of what it reads: needs "
                         "consumer_waits = 'reads' and copy_granularity = 'pass'",
                         field="schedule.consumer_chunks")
    return cfg.opt("chunks") > 1 and cfg.gpus > 1


def _split_renders(renders: list[PassTask], chunks: int) -> list[PassTask]:
    """Each of GPU 1's passes as `chunks` sub-passes in order (`render.X#c`, each 1/chunks of
    the work plus the pass's fixed cost); the Vulkan runner does not split passes."""
    why = MappingProxyType({"unsupported": "schedule.producer_chunks: passes rendered in "
                            "pieces are simulated only"})
    out: list[PassTask] = []
    for task in renders:
        work = MappingProxyType({k: v / chunks for k, v in task.work.items()})
        for c in range(chunks):
            deps = task.deps if c == 0 else (Dep(out[-1].name),)
            if c == 0 and out:
                deps = (Dep(out[-1].name),) + task.deps[1:]
            out.append(replace(task, name=f"{task.name}#{c}", work=work, deps=deps, params=why))
    return out


def _consumer(cfg: ScheduleConfig, scene: Scene, group: str,
              readers: dict[str, tuple[str, ...]] | None) -> str:
    """The task after which a copy group's destination buffer may be overwritten."""
    if readers is None:
        first = _gpu0_first(cfg, scene)
        return f"render.{first}" if first else "present"
    reading = [p for p, groups in readers.items() if group in groups]
    return f"render.{reading[-1]}" if reading else "present"


def _readers(cfg: ScheduleConfig, scene: Scene,
             split: int) -> dict[str, tuple[str, ...]] | None:
    """With consumer_waits = 'reads': every GPU 0 pass (in order) -> the copy groups whose
    arrival it waits for; None with 'all' or one GPU. A pass reads the GPU 1 outputs `reads` lists,
    else the scene passes its `reads` names, else (a filter) its `inputs` passes that ran on GPU 1."""
    given = cfg.opt("reads")
    if cfg.opt("consumer_waits") == "all":
        if given:
            raise InputError("reads applies with consumer_waits = 'reads'", field="schedule.reads")
        return None
    if cfg.gpus == 1:  # nothing crosses; the same file runs as the one-GPU baseline
        _check_names(given, [p.name for p in scene.passes])
        return None
    first = [p.name for p in scene.passes[:split]]
    rest = scene.passes[split:]
    for name, sources in given.items():
        if name not in {p.name for p in rest}:
            raise InputError(f"{name!r} is not a pass on GPU 0 (those are "
                             f"{[p.name for p in rest]})", field=f"schedule.reads.{name}")
        if not isinstance(sources, list) or not all(s in first for s in sources):
            raise InputError(f"expected a list of passes that run on GPU 1 ({first}), got "
                             f"{sources!r}", field=f"schedule.reads.{name}")
    frame_copy = cfg.opt("copy_granularity") == "frame"
    out: dict[str, tuple[str, ...]] = {}
    for index, spec in enumerate(scene.passes[split:], start=split):
        sources = given.get(spec.name)
        if sources is None and spec.reads:  # the scene's own reads: those that ran on GPU 1
            sources = [s for s in spec.reads if s in first]
        elif sources is None and spec.kind == "filter":
            found = filter_sources(scene.passes, index)
            sources = [s for s in found if s in first] if not isinstance(found, str) else []
        sources = [s for s in sources or () if _output_bytes(_spec(scene, s)) or frame_copy]
        out[spec.name] = tuple(dict.fromkeys("out" if frame_copy else f"out.{s}" for s in sources))
    return out


def _check_names(given: dict, names: list[str]) -> None:
    """`reads` names scene passes only (checked on one GPU, where no pass runs on GPU 1)."""
    for name, sources in given.items():
        if name not in names or not isinstance(sources, list) or not all(s in names for s in sources):
            raise InputError(f"expected scene passes ({names}) read by a scene pass, got "
                             f"{name!r} = {sources!r}", field=f"schedule.reads.{name}")


def _spec(scene: Scene, name: str) -> PassSpec:
    return next(p for p in scene.passes if p.name == name)


def _reading_passes(rest: tuple[PassSpec, ...], scene: Scene, fif: int,
                    readers: dict[str, tuple[str, ...]], arrivals: list[tuple[str, str]],
                    pieces: int = 1) -> list[PassTask]:
    """GPU 0's passes in order; each also waits for every piece of the groups it reads. With
    `pieces` > 1 a reading pass runs as that many sub-passes, piece c after chunk c of each
    group it reads (arrivals come in chunk order per group)."""
    out: list[PassTask] = []
    for task, spec in zip(_passes(0, rest, scene, (Dep("present", -fif),)), rest):
        groups = readers[spec.name]
        if out:
            task = replace(task, deps=(Dep(out[-1].name),) + task.deps[1:])
        if pieces == 1 or not groups:
            out.append(_with_deps(task, tuple(Dep(a) for g, a in arrivals if g in groups)))
            continue
        chunk = {g: [a for gg, a in arrivals if gg == g] for g in groups}
        split = _split_renders([task], pieces)
        for c, sub in enumerate(split):
            if c:
                sub = replace(sub, deps=(Dep(out[-1].name),))
            out.append(_with_deps(sub, tuple(Dep(chunk[g][c]) for g in groups)))
    return out


def _needed_on_gpu0(scene: Scene, split: int) -> set[str]:
    """GPU 1's passes whose output GPU 0 uses: sampled by its filters, or presented."""
    needed = {scene.passes[-1].name} if split == len(scene.passes) else set()
    for index in range(split, len(scene.passes)):
        if scene.passes[index].kind == "filter":
            sources = filter_sources(scene.passes, index)
            if not isinstance(sources, str):
                needed.update(n for n in sources if n in {p.name for p in scene.passes[:split]})
    return needed


def _gpu0_first(cfg: ScheduleConfig, scene: Scene) -> str | None:
    """The first pass on GPU 0 (it consumes the intermediate results), if any."""
    split = cfg.opt("split_at")
    return scene.passes[split].name if split < len(scene.passes) else None


def _with_deps(task: PassTask, extra: tuple[Dep, ...]) -> PassTask:
    return replace(task, deps=task.deps + extra)


def _interleave(renders: list[PassTask], copies: list[Task]) -> list[Task]:
    """Submission order: each pass followed by the copies that read its output, so copies
    recorded on the graphics queue run between passes rather than after all of them."""
    after: dict[str, list[Task]] = {}
    rest: list[Task] = []
    names = {r.name for r in renders}
    for c in copies:  # one pass over the copies: linear in chunks, not quadratic
        if c.deps and c.deps[0].task in names:
            after.setdefault(c.deps[0].task, []).append(c)
        else:
            rest.append(c)
    out: list[Task] = []
    for r in renders:
        out.append(r)
        out.extend(after.get(r.name, ()))
    return out + rest
