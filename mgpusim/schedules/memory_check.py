"""Resident data per GPU, checked against its memory before anything runs.

Each GPU holds a share of the scene's data set (geometry + decoded textures,
`scene.dataset_bytes`), its render targets, and the device-local buffers that receive data
from other GPUs ("staging"); every schedule declares these footprints when it builds its
program. Sort-last is the strategy whose share shrinks with N, which is why several GPUs can
hold data sets one cannot; every other strategy keeps the whole data set on every GPU that
renders. An experiment that does not fit is reported (which GPU, by how
much), never simulated as if it fitted. :func:`max_dataset_bytes` answers "what is the
largest data set this strategy can hold on these GPUs".
"""
from __future__ import annotations

from dataclasses import replace

from mgpusim.model.errors import InputError
from mgpusim.model.scene import Scene
from mgpusim.schedules.base import Footprint, FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program


def footprints(program: FrameProgram, scene: Scene) -> tuple[Footprint, ...]:
    """Per-GPU resident data of a built program, as its schedule declared it (one full set per
    GPU where it declared none)."""
    if program.footprints:
        return program.footprints
    full = scene.color_bytes + scene.depth_bytes
    return tuple(Footprint(i, 1.0, full, 0) for i in range(program.gpus))


def memory_report(program: FrameProgram, exp: Experiment) -> dict[str, dict[str, int | float | list[str]]]:
    """used / capacity per GPU, for the summary (and the sections it holds, where the scene has them)."""
    out: dict[str, dict[str, int | float | list[str]]] = {}
    for fp in footprints(program, exp.scene):
        cap = exp.profile.gpus[fp.gpu].memory_bytes
        used = fp.used(exp.scene.dataset_bytes)
        out[f"gpu{fp.gpu}"] = {"used_bytes": used, "capacity_bytes": cap,
                               "fraction": round(used / cap, 6)}
        if exp.scene.sections:
            out[f"gpu{fp.gpu}"]["sections"] = list(held_sections(fp, exp.scene))
    return out


def held_sections(fp: Footprint, scene: Scene) -> tuple[str, ...]:
    """The sections a GPU holds: those its schedule gave it, else all of them where it holds
    the whole data set, else none."""
    if fp.sections or not scene.sections:
        return fp.sections
    return tuple(s.name for s in scene.sections) if fp.share >= 1 else ()


def sections_that_fit(fp: Footprint, scene: Scene, capacity: int) -> tuple[str, ...]:
    """Of the sections a GPU is given, the longest leading run that fits beside its render
    targets and receive buffers (sections load in order, each whole)."""
    free = capacity - fp.targets - fp.staging
    fit: list[str] = []
    by_name = {s.name: s for s in scene.sections}
    for name in held_sections(fp, scene):
        free -= by_name[name].bytes
        if free < 0:
            break
        fit.append(name)
    return tuple(fit)


def check_memory(program: FrameProgram, exp: Experiment) -> None:
    """Raise InputError naming the first GPU whose resident data exceeds its memory."""
    data = exp.scene.dataset_bytes
    for fp in footprints(program, exp.scene):
        gpu = exp.profile.gpus[fp.gpu]
        used = fp.used(data)
        if used > gpu.memory_bytes:
            over = used - gpu.memory_bytes
            raise InputError(
                f"gpu{fp.gpu} ({gpu.name}, {_gib(gpu.memory_bytes)}) overflows by {over} bytes "
                f"({_gib(over)}): data set share {_gib(fp.data(data))} + render targets "
                f"{_gib(fp.targets)} + receive buffers {_gib(fp.staging)} = {_gib(used)} under "
                f"schedule {program.schedule!r} with {program.gpus} GPU(s)"
                + _sections_note(fp, exp.scene, gpu.memory_bytes),
                file=exp.file, field=_blame(fp, data, bool(exp.scene.sections)))


def _sections_note(fp: Footprint, scene: Scene, capacity: int) -> str:
    """Which of the GPU's sections fit (empty without sections)."""
    held = held_sections(fp, scene)
    if not held:
        return ""
    fit = sections_that_fit(fp, scene, capacity)
    return (f"; it holds sections {', '.join(held)}, of which only the first {len(fit)} fit"
            + (f" ({', '.join(fit)})" if fit else ""))


def _blame(fp: Footprint, dataset_bytes: int, sectioned: bool = False) -> str:
    """The input behind the largest part of the footprint: the data set, the image size (render
    targets) or what crosses GPUs per frame times its buffering (receive buffers)."""
    data = "scene.sections" if sectioned else "scene.dataset_bytes"
    parts = {data: fp.data(dataset_bytes), "scene.width x scene.height": fp.targets,
             "receive buffers (schedule.buffers x bytes crossing per frame)": fp.staging}
    return max(parts, key=parts.__getitem__)


def max_dataset_bytes(exp: Experiment) -> int:
    """The largest `scene.dataset_bytes` this experiment's strategy fits on its GPUs."""
    program = build_program(exp)
    best: int | None = None
    for fp in footprints(program, exp.scene):
        fp = replace(fp, section_bytes=None)  # the data set scaled as a whole
        free = exp.profile.gpus[fp.gpu].memory_bytes - fp.targets - fp.staging
        if free < 0:
            return 0
        if fp.share > 0:
            fit = int(free / fp.share)
            while fp.used(fit) > exp.profile.gpus[fp.gpu].memory_bytes:  # rounding guard
                fit -= 1
            best = fit if best is None else min(best, fit)
    return best if best is not None else 0


def _gib(n: int | float) -> str:
    return f"{n / 2**30:.2f} GiB"

