"""Resident data per GPU, checked against its memory before anything runs.

Each GPU holds a share of the scene's data set (geometry + decoded textures,
`scene.dataset_bytes`), its render targets, and the device-local buffers that receive data
from other GPUs ("staging"). Sort-last is the strategy whose share shrinks with N, which is
why several GPUs can hold data sets one cannot; every other strategy keeps the whole data set
on every GPU that renders. An experiment that does not fit is reported (which GPU, by how
much), never simulated as if it fitted. :func:`max_dataset_bytes` answers "what is the
largest data set this strategy can hold on these GPUs".
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .errors import InputError
from .experiment import Experiment
from .scene import Scene
from .schedules.base import FrameProgram


@dataclass(frozen=True)
class Footprint:
    """One GPU's resident data: `share` of the data set plus fixed buffers (bytes)."""

    gpu: int
    share: float
    targets: int
    staging: int

    def used(self, dataset_bytes: int) -> int:
        return int(round(self.share * dataset_bytes)) + self.targets + self.staging


Rule = Callable[[FrameProgram, Scene, int], list[Footprint]]


def _full(scene: Scene) -> int:
    return scene.color_bytes + scene.depth_bytes


def _five_step(program: FrameProgram, scene: Scene, n: int) -> list[Footprint]:
    """Sort-first: tile targets, colour crosses; sort-last: full targets, colour + depth."""
    buffers = int(program.notes.get("buffers", 2))
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    if "tile_rows" in program.notes:
        rows = program.notes["tile_rows"]
        targets = [scene.width * r * bpp for r in rows]
        sent = [scene.width * r * scene.color_bytes_per_pixel for r in rows]
        share = [1.0] * n
    else:
        targets = [_full(scene)] * n
        sent = [_full(scene)] * n
        share = [float(program.notes.get("geometry_share", 1.0 / n))] * n
    out = [Footprint(0, share[0], targets[0] + scene.color_bytes, buffers * sum(sent[1:]))]
    out += [Footprint(i, share[i], buffers * targets[i], 0) for i in range(1, n)]
    return out


def _afr(program: FrameProgram, scene: Scene, n: int) -> list[Footprint]:
    history = int(program.notes.get("history_bytes", 0))
    out = [Footprint(0, 1.0, _full(scene) + history, (n - 1) * scene.color_bytes)]
    return out + [Footprint(i, 1.0, _full(scene) + history, 0) for i in range(1, n)]


def _pipelining(program: FrameProgram, scene: Scene, n: int) -> list[Footprint]:
    moved = int(program.notes.get("bytes_per_frame", 0))
    buffers = int(program.notes.get("buffers", 2))
    out = [Footprint(0, 1.0, _full(scene), buffers * moved)]
    return out + ([Footprint(1, 1.0, buffers * moved, 0)] if n > 1 else [])


def _xr(program: FrameProgram, scene: Scene, n: int) -> list[Footprint]:
    bpp = scene.color_bytes_per_pixel + scene.depth_bytes_per_pixel
    views = list(program.notes.get("view_pixels", ()))
    buffers = int(program.notes.get("buffers", 2)) if program.notes.get("scaling") == "strong" else 1
    final = 2 * scene.pixels * scene.color_bytes_per_pixel
    if program.notes.get("mode") == "simulated" or n == 1:
        return [Footprint(0, 1.0, buffers * sum(views) * bpp + final, 0)]
    out = [Footprint(0, 1.0, buffers * views[0] * bpp + final, sum(views[1:]) * bpp)]
    return out + [Footprint(i, 1.0, buffers * views[i] * bpp, 0) for i in range(1, n)]


def _particles(program: FrameProgram, scene: Scene, n: int) -> list[Footprint]:
    """Vertex buffers double-buffered on both GPUs; the 2-float4 calc buffer where updated."""
    count = int(program.notes.get("particles", 0))
    vertex = 2 * count * 192
    calc = count * 32
    pg = int(program.notes.get("particle_gpu", 0))
    out = [Footprint(0, 1.0, _full(scene) + vertex + (calc if pg == 0 else 0), 0)]
    out += [Footprint(i, 0.0, vertex + calc if i == pg else 0, 0) for i in range(1, n)]
    return out


RULES: dict[str, Rule] = {"sort_first": _five_step, "sort_last": _five_step, "afr": _afr,
                          "pipelining": _pipelining, "xr": _xr, "particles": _particles}


def footprints(program: FrameProgram, scene: Scene) -> list[Footprint]:
    """Per-GPU resident data of a built program (one full set per GPU for unknown schedules)."""
    rule = RULES.get(program.schedule)
    if rule is None:
        return [Footprint(i, 1.0, _full(scene), 0) for i in range(program.gpus)]
    return rule(program, scene, program.gpus)


def memory_report(program: FrameProgram, exp: Experiment) -> dict[str, dict[str, int | float]]:
    """used / capacity per GPU, for the summary."""
    out = {}
    for fp in footprints(program, exp.scene):
        cap = exp.profile.gpus[fp.gpu].memory_bytes
        used = fp.used(exp.scene.dataset_bytes)
        out[f"gpu{fp.gpu}"] = {"used_bytes": used, "capacity_bytes": cap,
                               "fraction": round(used / cap, 6)}
    return out


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
                f"({_gib(over)}): data set share {_gib(round(fp.share * data))} + render targets "
                f"{_gib(fp.targets)} + receive buffers {_gib(fp.staging)} = {_gib(used)} under "
                f"schedule {program.schedule!r} with {program.gpus} GPU(s)",
                file=exp.file, field=_blame(fp, data))


def _blame(fp: Footprint, dataset_bytes: int) -> str:
    """The input behind the largest part of the footprint: the data set, the image size (render
    targets) or what crosses GPUs per frame times its buffering (receive buffers)."""
    parts = {"scene.dataset_bytes": fp.share * dataset_bytes, "scene.width x scene.height": fp.targets,
             "receive buffers (schedule.buffers x bytes crossing per frame)": fp.staging}
    return max(parts, key=parts.__getitem__)


def max_dataset_bytes(exp: Experiment) -> int:
    """The largest `scene.dataset_bytes` this experiment's strategy fits on its GPUs."""
    from .simulate import build_program
    program = build_program(exp)
    best: int | None = None
    for fp in footprints(program, exp.scene):
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

