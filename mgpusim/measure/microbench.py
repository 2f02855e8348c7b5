"""Microbenchmark sweeps of the pass library: the data the cost-model calibration fits.

Why this shape: one tidy row per (simulated GPU, parameter combination, repetition), with every
parameter of the pass as a column (defaults filled in), so the calibration can group by any
knob. Warm-up runs (first-use page faults, shader JIT) are run and discarded; every measured
repetition is kept. With several GPUs every repetition is submitted to all of them at once, so
the table shows their contention (on lavapipe they share the CPU). `overlap` is the one pass
that is two: pieces of work on two queues of one GPU, alone and at once (:mod:`.overlap`).
"""
from __future__ import annotations

import itertools
import re
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import pandas as pd

from mgpusim.measure import overlap as overlap
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import MESH_OPTIONS, MESH_PLACE, mesh_placement
from mgpusim.real.host.memcpy import HostCopy
from mgpusim.real.passes.particle_update import ParticleUpdate
from mgpusim.real.passes.standalone import (
    CompositeSortFirst,
    CompositeSortLast,
    FilterPass,
    FragmentLoop,
    Mesh,
    ParticleRender,
    Present,
)
from mgpusim.real.vulkan.copies import CopyD2D, CopyD2H, CopyH2D
from mgpusim.real.vulkan.device import Gpu


def _mesh(gpu: Gpu, p: dict[str, Any]) -> Mesh:
    place = mesh_placement(p)  # (Mesh refuses a shape or cull it cannot draw, before allocating)
    view = place.mesh_view(int(p["triangles"]), p["shape"], p["cull"])
    return Mesh(gpu, int(p["width"]), int(p["height"]), view.triangles, first=view.first,
                count=view.count, eye=view.eye, rect=place.rect, shape=view.shape, cull=view.cull)


@dataclass(frozen=True)
class PassSpec:
    """A measurable pass: its parameters with defaults and how to build it on a Gpu."""

    name: str
    params: dict[str, int | str]
    build: Callable[..., Any]
    doc: str
    host: bool = False


PASSES: dict[str, PassSpec] = {s.name: s for s in (
    PassSpec("fragment_loop", {"width": 1024, "height": 768, "iterations": 1000},
             lambda g, p: FragmentLoop(g, p["width"], p["height"], p["iterations"]),
             "full-screen rectangle, fragment shader loops ITER times"),
    PassSpec("mesh", {"width": 1024, "height": 768, "triangles": 100_000, **MESH_PLACE, **MESH_OPTIONS},
             lambda g, p: _mesh(g, p),
             "T triangles of a mesh into RGBA8 + D16, drawn where PLACE says: whole, "
             "or share=K/N;eye=left|right;column=K/N;row=K/N (sort-last share, stereo eye, XR "
             "half-eye columns, sort-first strip); SHAPE torus (ours) or sphere (vmgpu's mesh, "
             "drawn as vmgpu draws it), CULL none or back"),
    PassSpec("composite_sort_first", {"width": 1024, "height": 768, "inputs": 2},
             lambda g, p: CompositeSortFirst(g, p["width"], p["height"], p["inputs"]),
             "one rectangle per contribution sampling its tile"),
    PassSpec("composite_sort_last", {"width": 1024, "height": 768, "inputs": 2},
             lambda g, p: CompositeSortLast(g, p["width"], p["height"], p["inputs"]),
             "full-screen quad per contribution, colour + depth, depth-tested"),
    PassSpec("present", {"width": 1024, "height": 768},
             lambda g, p: Present(g, p["width"], p["height"]),
             "the frame copied into the displayed image (the runner's present)"),
    PassSpec("filter", {"width": 1024, "height": 768, "iterations": 1000, "inputs": 2},
             lambda g, p: FilterPass(g, p["width"], p["height"], p["iterations"], p["inputs"]),
             "fragment loop sampling 1-4 inputs at its pixel (the pipelining chain's "
             "consumers; the temporal pass with 2)"),
    PassSpec("particle_update", {"particles": 65_536},
             lambda g, p: ParticleUpdate(g, p["particles"]),
             "compute: update P particles and build 6-vertex billboards"),
    PassSpec("particle_render", {"width": 1024, "height": 768, "particles": 65_536},
             lambda g, p: ParticleRender(g, p["width"], p["height"], p["particles"]),
             "draw P additive billboards"),
    PassSpec("copy_d2h", {"bytes": 1 << 22, "queue": "graphics"},
             lambda g, p: CopyD2H(g, p["bytes"], p["queue"]), "image -> host-visible buffer"),
    PassSpec("copy_h2d", {"bytes": 1 << 22, "queue": "graphics"},
             lambda g, p: CopyH2D(g, p["bytes"], p["queue"]), "host-visible buffer -> image"),
    PassSpec("copy_d2d", {"bytes": 1 << 22, "queue": "graphics"},
             lambda g, p: CopyD2D(g, p["bytes"], p["queue"]), "device buffer -> device buffer"),
    PassSpec("host_copy", {"bytes": 1 << 22, "threads": 1},
             lambda g, p: HostCopy(p["bytes"], p["threads"]),
             "host -> host on K threads, chunks >= 512 KiB", host=True),
    PassSpec("overlap", dict(overlap.PARAMS), lambda g, p: None,
             "two queues of one GPU alone and at once (pair: " + ", ".join(overlap.PAIRS)
             + "): fragment loop / particle update / copy on the copy engine"),
)}

_SUFFIX = {"": 1, "k": 1000, "m": 10**6, "g": 10**9, "kib": 1 << 10, "mib": 1 << 20,
           "gib": 1 << 30, "ki": 1 << 10, "mi": 1 << 20, "gi": 1 << 30}


def parse_value(text: str, default: int | str, field: str) -> int | str:
    """An int (with optional k/M/G or KiB/MiB/GiB suffix) where the default is an int."""
    if isinstance(default, str):
        return text
    m = re.fullmatch(r"\s*(\d+)\s*([A-Za-z]*)\s*", text)
    if not m or m.group(2).lower() not in _SUFFIX:
        raise InputError(f"expected an integer (optionally with k/M/G or KiB/MiB/GiB), "
                         f"got {text!r}", field=field)
    return int(m.group(1)) * _SUFFIX[m.group(2).lower()]


def spec(name: str) -> PassSpec:
    if name not in PASSES:
        raise InputError(f"unknown pass {name!r}; known: {', '.join(PASSES)}", field="--pass")
    return PASSES[name]


def parse_sweeps(pass_name: str, sweeps: Iterable[str]) -> dict[str, list[int | str]]:
    """`PARAM=V1,V2,...` strings -> {param: [values]} checked against the pass's parameters."""
    params = spec(pass_name).params
    out: dict[str, list[int | str]] = {}
    for item in sweeps:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not values:
            raise InputError(f"expected PARAM=V1,V2,..., got {item!r}", field="--sweep")
        if key not in params:
            raise InputError(f"{pass_name} has no parameter {key!r}; it has "
                             f"{', '.join(params)}", field="--sweep")
        out[key] = [parse_value(v, params[key], key) for v in values.split(",")]
    return out


def combinations(pass_name: str, sweeps: dict[str, list[int | str]]) -> list[dict[str, Any]]:
    params = spec(pass_name).params
    keys = list(sweeps)
    return [{**params, **dict(zip(keys, combo))}
            for combo in itertools.product(*(sweeps[k] for k in keys))]


def measure(pass_name: str, gpus: Sequence[Gpu], sweeps: dict[str, list[int | str]], *,
            reps: int = 5, warmup: int = 2,
            progress: Callable[[int], object] | None = None) -> pd.DataFrame:
    """Run every combination on every GPU; one row per GPU x combination x repetition. Several
    GPUs run each repetition at once (they compete, as in a multi-GPU frame); one GPU's rows
    also have the process's CPU time of each pass."""
    if reps < 1 or warmup < 0:
        raise InputError(f"need reps >= 1 and warmup >= 0, got {reps}, {warmup}")
    ps = spec(pass_name)
    rows: list[dict[str, Any]] = []
    for params in combinations(pass_name, sweeps):
        if pass_name == "overlap":
            rows += overlap.measure_pair(gpus, params, reps, warmup, lambda: ("measure", next(_KEYS)))
        elif ps.host:
            work = ps.build(None, params)
            try:
                for rep in range(-warmup, reps):
                    start, end = work.run()
                    if rep >= 0:
                        rows.append({"device": "host", "gpu": "host", "gpus": 1, "pass": pass_name,
                                     **params, "repetition": rep, "duration_ns": end - start,
                                     "bytes": work.bytes})
            finally:
                work.destroy()
        else:
            works = [ps.build(g, params) for g in gpus]
            keys = [("measure", next(_KEYS)) for _ in works]
            together = len(gpus) > 1
            try:
                for rep in range(-warmup, reps):
                    subs, cpu = (_together(gpus, works, keys, pass_name) if together
                                 else _one_by_one(gpus, works, keys, pass_name))
                    for g, w, s, c in zip(gpus, works, subs, cpu):
                        if rep >= 0:
                            rows.append({"device": g.info.name, "gpu": g.name,
                                         "gpus": len(gpus) if together else 1,
                                         "lp_threads": g.cpu_threads, "pass": pass_name,
                                         **params, "repetition": rep,
                                         "duration_ns": s.duration_ns, "cpu_ns": c,
                                         "bytes": w.bytes})
            finally:
                for g, w, k in zip(gpus, works, keys):
                    g.forget(k)
                    w.destroy()
        if progress is not None:
            progress(1)
    return pd.DataFrame(rows)


#: Keys of the measured passes' pre-recorded command buffers (unique: ids of destroyed passes
#: could come back).
_KEYS = itertools.count()


def _one_by_one(gpus: Sequence[Gpu], works: Sequence[Any], keys: Sequence[Any],
                label: str) -> tuple[list, list]:
    """Each GPU's pass alone, with the process's CPU time while it ran (all threads: on lavapipe
    the GPU's rasterizer and queue threads; cpu_ns / duration_ns is the cores it keeps busy, plus
    a per-submission overhead that `calibrate` fits). Command buffers are recorded once (`key`),
    so that Python's recording is not in that time."""
    subs, cpu = [], []
    for g, w, k in zip(gpus, works, keys):
        start = time.process_time_ns()
        subs.append(g.submit(w.queue, w.record, label=label, key=k).wait())
        cpu.append(time.process_time_ns() - start)
    return subs, cpu


def _together(gpus: Sequence[Gpu], works: Sequence[Any], keys: Sequence[Any],
              label: str) -> tuple[list, list]:
    """All GPUs' passes at once (they compete); CPU time is not one pass's here."""
    subs = [g.submit(w.queue, w.record, label=label, key=k) for g, w, k in zip(gpus, works, keys)]
    for s in subs:
        s.wait()
    return subs, [float("nan")] * len(subs)


def write_table(df: pd.DataFrame, path: str) -> None:
    """CSV or Parquet by the file's extension."""
    lower = path.lower()
    if lower.endswith(".csv"):
        df.to_csv(path, index=False)
    elif lower.endswith((".parquet", ".pq")):
        try:
            df.to_parquet(path, index=False)
        except ImportError as exc:
            raise InputError(f"writing Parquet needs pyarrow ({exc}); use a .csv file",
                             file=path) from None
    else:
        raise InputError("expected a .csv or .parquet file", file=path, field="--out")
