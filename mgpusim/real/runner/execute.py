"""`run_program` / `run_experiment`: execute the simulator's FrameProgram on Vulkan devices.

Why the same program: `mgpusim.schedules.program.build_program(exp)` is what the simulator runs; the
runner executes those very tasks (queues, dependencies, submission order, buffering), so a
measured trace and a simulated one differ only in where the durations come from.

Timing: `prewarm_frames` untimed frames first (shader JIT, first-touch page faults, every
buffered copy used once), then `program.frames` frames, all traced; the summary counts
steady state from `program.warmup_frames` on, exactly as the simulator's does.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pandas as pd

from mgpusim.model.errors import InputError, MgpusimError, ScheduleError
from mgpusim.model.limits import MAX_RECORDED_FRAMES, WHY_RECORDED
from mgpusim.model.profile import HardwareProfile
from mgpusim.real.runner import native
from mgpusim.real.runner.executor import Executor
from mgpusim.real.runner.native import NativeExecutor
from mgpusim.real.runner.plan import build_nodes
from mgpusim.real.runner.resources import Resources
from mgpusim.real.runner.work import GpuWork, Work, build_work
from mgpusim.real.vulkan.copies import download
from mgpusim.real.vulkan.device import Gpu
from mgpusim.results.summary import frames_from_trace, summarize, task_rates
from mgpusim.results.trace import make_submissions, make_trace
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program, run_config


@dataclass
class RunResult:
    """A measured run: `.trace`, `.frames`, `.summary` as the simulator's Result, plus the final
    displayed image (H x W x 4 uint8) and the frame's depth (H x W uint16, sort-last only)."""

    summary: dict[str, Any]
    trace: pd.DataFrame
    frames: pd.DataFrame
    image: np.ndarray
    depth: np.ndarray | None = None
    config: dict[str, Any] = field(default_factory=dict)
    machine: dict[str, Any] = field(default_factory=dict)
    #: resources named in `read=`, every buffered copy, as bytes (uint8) after the run
    readback: dict[str, list[np.ndarray]] = field(default_factory=dict)
    #: the host side of each GPU task (:data:`mgpusim.results.trace.SUBMISSION_COLUMNS`), same clock
    submissions: pd.DataFrame | None = None


def run_program(program: FrameProgram, gpus: Sequence[Gpu], *, host_threads: int = 1,
                prewarm_frames: int | None = None, rebase: bool = True,
                stall_timeout_s: float = 120.0, read: Sequence[str] = (),
                runner: str | None = None) -> RunResult:
    """Execute `program` on `gpus` (simulated GPU i = gpus[i]); the GPUs stay open.

    The default prewarm is a whole number of template periods (AFR's frame f runs on GPU
    f mod N), so the timed run's frame 0 continues where the prewarm left off. `read` names
    resources to read back after the run (RunResult.readback). `runner`: the executor (auto,
    python or native; default MGPUSIM_RUNNER, docs/runner.md)."""
    if host_threads < 1:
        raise InputError(f"must be >= 1, got {host_threads}", field="host_threads")
    declared = program.resources
    if declared is None:
        raise ScheduleError(f"schedule {program.schedule!r} declares no resources (what its "
                            f"tasks read and write): the Vulkan runner cannot execute it yet")
    if len(gpus) < program.gpus:
        raise InputError(f"the program needs {program.gpus} GPU(s), got {len(gpus)}", field="gpus")
    gpus = list(gpus)
    res = Resources(declared, gpus)
    owned: list[Any] = []
    try:
        works: list[dict[str, Work]] = [
            {t.name: build_work(t, gpus, res, host_threads, owned) for t in tasks}
            for tasks in program.templates]
        period = len(program.templates)
        warm = prewarm_frames if prewarm_frames is not None else -(-max(
            2, program.buffers, period) // period) * period
        core_name, runner_note = native.choose(program, build_nodes(program, works, period),
                                               any(g.info.is_lavapipe for g in gpus), runner)
        core = NativeExecutor if core_name == "native" else Executor
        if warm:
            core(build_nodes(program, works, warm), host_threads, stall_timeout_s,
                 program).execute()
        timed = core(build_nodes(program, works, program.frames), host_threads,
                     stall_timeout_s, program)
        rows = timed.execute()
        for g in gpus:
            g.wait_idle()
        image, depth = _final_image(gpus[0], res)
        readback = {name: _read(gpus, res, name) for name in read}
    finally:
        for g in gpus:
            try:
                g.wait_idle()
            except MgpusimError:  # e.g. a lost device: clean up anyway, keep the first error
                pass
        for obj in reversed(owned):
            obj.destroy()
        res.destroy()
    origin = min(r[5] for r in rows)
    submitted = timed.submissions
    if rebase:
        rows = [r[:5] + (r[5] - origin, r[6] - origin) + r[7:] for r in rows]
        submitted = [r[:4] + tuple(t - origin for t in r[4:]) for r in submitted]
    trace = make_trace(rows)
    frames = frames_from_trace(trace, _present_step(program))
    summary = summarize(frames, trace, program.warmup_frames)
    summary["clock_origin_ns"] = int(origin) if rebase else 0
    summary["step_mean_ms"] = {k: float(v) / 1e6 for k, v in (trace["end_ns"] - trace["start_ns"])
                               .groupby(trace["step"]).mean().items()}
    fallbacks = sorted({f"{w.task.name}: {w.task.queue} -> gpu{w.device}.graphics"
                        for ws in works for w in ws.values()
                        if isinstance(w, GpuWork) and w.fallback})
    if fallbacks:
        summary["queue_fallbacks"] = fallbacks
    summary["runner"] = core_name
    if runner_note:
        summary["runner_note"] = runner_note
    _skips(program, timed, summary)
    return RunResult(summary, trace, frames, image, depth, readback=readback,
                     submissions=make_submissions(submitted))


def _skips(program: FrameProgram, timed: Executor | NativeExecutor, summary: dict[str, Any]) -> None:
    """Skipped instances as the simulator reports them (`skipped_tasks`, `task_rates_hz`),
    plus what the run chose at submit time (`skipped_frames`, `read_frames`)."""
    skipped = timed.skipped_frames
    if skipped:
        summary["skipped_tasks"] = {k: len(v) for k, v in skipped.items()}
        summary["skipped_frames"] = {k: list(v) for k, v in skipped.items()}
    if timed.read_frames:
        summary["read_frames"] = {k: [v.get(f) for f in range(program.frames)]
                                  for k, v in timed.read_frames.items()}
    rates = task_rates(program, skipped, summary)
    if rates:
        summary["task_rates_hz"] = rates


def _read(gpus: Sequence[Gpu], res: Resources, name: str) -> list[np.ndarray]:
    """Every buffered copy of resource `name` (colour bytes of an image), read back."""
    r = res.resource(name)
    device = r.device if r.device is not None else r.shared_by[0]
    if r.kind == "image":
        return [download(gpus[device], colour) for colour, _d in res.images(name)]
    return [download(gpus[device], res.buffer(name, device, s)) for s in range(r.buffers)]


def _present_step(program: FrameProgram) -> str:
    task = next(t for t in program.templates[0] if t.name == program.present_task)
    return task.step


def _final_image(gpu: Gpu, res: Resources) -> tuple[np.ndarray, np.ndarray | None]:
    """The displayed image (RGBA8) and the frame's depth (D16), read back after the run."""
    display = res.declared.get("gpu0.display")
    name = "gpu0.display" if display is not None else "gpu0.frame"
    colour = res.images(name)[0][0]
    image = download(gpu, colour).reshape(colour.height, colour.width, 4)
    depth_img = res.images("gpu0.frame")[0][1] if "gpu0.frame" in res.declared else None
    depth = None
    if depth_img is not None:
        depth = download(gpu, depth_img).view(np.uint16).reshape(depth_img.height, depth_img.width)
    return image, depth


def profile_lp_threads(profile: HardwareProfile, gpus: int) -> list[int | None] | None:
    """The rasterizer threads a lavapipe profile gives each of `gpus` simulated GPUs (None:
    not a lavapipe profile, or it does not say): a run measures the machine the profile
    describes."""
    if not profile.host.gpus_share_cpu:
        return None
    threads = [profile.gpus[min(i, len(profile.gpus) - 1)].cpu_threads for i in range(gpus)]
    return threads if any(t is not None for t in threads) else None


def run_experiment(exp: Experiment, *, devices: Sequence[int] | None = None,
                   lp_threads: Sequence[int | None] | None = None, host_threads: int | None = None,
                   prewarm_frames: int | None = None, validation: bool | None = None,
                   read: Sequence[str] = (), runner: str | None = None) -> RunResult:
    """Build `exp`'s program as the simulator does, open its GPUs, run it, close them.

    `devices[i]`: physical device of simulated GPU i (NVIDIA; default i mod count; lavapipe
    always gives each simulated GPU its own instance). `lp_threads[i]`: LP_NUM_THREADS of GPU i
    (default: a lavapipe profile's `cpu_threads` of that GPU, the threads it was calibrated
    with). `host_threads`: memcpy threads (default: the profile's `host.memcpy_threads`, the
    simulator's split). `runner`: as run_program's."""
    from mgpusim.real.runner.gpu_map import open_gpus  # noqa: PLC0415
    from mgpusim.real.vulkan.machine import close_gpus, machine_record  # noqa: PLC0415

    if exp.schedule.frames > MAX_RECORDED_FRAMES:  # hardware never fast-forwards: every frame is kept
        raise InputError(f"{exp.schedule.frames:,} frames: a measured run keeps every frame's "
                         f"records, at most {MAX_RECORDED_FRAMES:,} ({WHY_RECORDED})",
                         file=exp.file, field="schedule.frames")
    program = build_program(exp)
    threads = exp.profile.host.memcpy_threads if host_threads is None else host_threads
    if lp_threads is None:
        lp_threads = profile_lp_threads(exp.profile, program.gpus)
    gpus = open_gpus(program.gpus, devices=devices, lp_threads=lp_threads, validation=validation)
    try:
        result = run_program(program, gpus, host_threads=threads, prewarm_frames=prewarm_frames,
                             read=read, runner=runner)
        result.machine = machine_record(gpus, {"host_threads": threads})
    finally:
        close_gpus(gpus)
    result.config = {**run_config(exp, program), "measured": True, "host_threads": threads}
    return result
