"""The overlap microbenchmark: two pieces of work on two queues of one GPU, alone and at once.

Why: the queues of one GPU share it. A particle update on the compute queue slows a render on
the graphics queue, and a copy on the copy engine takes memory bandwidth from both. The model
gives each pair of queues an *overlap efficiency* (docs/queues.md). This measures it:
- `graphics`: a full-screen fragment loop (`width` x `height`, `iterations`), or with
  `graphics=particle_render` the particle draw (`particles` billboards blended into `width` x
  `height`): how much two pieces of work slow each other depends on what they are bound by;
- `compute`: the particle update (`particles`);
- `transfer`: a copy on the copy engine (`copy`: h2d, d2h or d2d, `bytes`).
Pairs: graphics_compute, graphics_transfer, compute_transfer on the queues of one VkDevice, and
`devices`: the graphics work on one VkDevice with the compute work on a second VkDevice of the
same physical GPU (two logical GPUs on one). Each repetition times A alone, B alone, then both
submitted at once; a queue family the device lacks falls back to the graphics queue (lavapipe
has one family), and the row says so in `missing`.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

from mgpusim.model.costs import overlap_efficiency
from mgpusim.model.errors import InputError
from mgpusim.real.passes.particle_update import ParticleUpdate
from mgpusim.real.passes.standalone import FragmentLoop, ParticleRender
from mgpusim.real.vulkan.copies import CopyD2D, CopyD2H, CopyH2D
from mgpusim.real.vulkan.device import Gpu

#: Each pair: the queue families of its two pieces of work, and whether they run on two
#: VkDevices of one physical GPU.
PAIRS: dict[str, tuple[str, str, bool]] = {
    "graphics_compute": ("graphics", "compute", False),
    "graphics_transfer": ("graphics", "transfer", False),
    "compute_transfer": ("compute", "transfer", False),
    "devices": ("graphics", "compute", True),
}
PARAMS: dict[str, int | str] = {"pair": "graphics_compute", "graphics": "fragment_loop",
                                "width": 1024, "height": 768, "iterations": 1000,
                                "particles": 1 << 20, "bytes": 1 << 26, "copy": "h2d"}
#: The graphics work the pairs can use (a pass kind of the cost model).
GRAPHICS = ("fragment_loop", "particle_render")
_COPIES: dict[str, Callable[..., Any]] = {"h2d": CopyH2D, "d2h": CopyD2H, "d2d": CopyD2D}


def _work(gpu: Gpu, family: str, p: dict[str, Any]) -> Any:
    if family == "graphics":
        if p["graphics"] not in GRAPHICS:
            raise InputError(f"must be one of {', '.join(GRAPHICS)}, got {p['graphics']!r}",
                             field="graphics")
        if p["graphics"] == "particle_render":
            return ParticleRender(gpu, p["width"], p["height"], p["particles"])
        return FragmentLoop(gpu, p["width"], p["height"], p["iterations"])
    if family == "compute":
        return ParticleUpdate(gpu, p["particles"])
    if p["copy"] not in _COPIES:
        raise InputError(f"must be one of {', '.join(_COPIES)}, got {p['copy']!r}", field="copy")
    return _COPIES[p["copy"]](gpu, p["bytes"], "transfer")


def gpus_needed(pairs: Sequence[int | str]) -> int:
    """VkDevices the pairs (a sweep's `pair` values) need: two for `devices`, else one."""
    return 2 if any(PAIRS[p][2] for p in pairs if p in PAIRS) else 1


def measure_pair(gpus: Sequence[Gpu], params: dict[str, Any], reps: int, warmup: int,
                 keys: Callable[[], Any]) -> list[dict[str, Any]]:
    """One row per repetition: A alone, B alone, A and B at once (host-clock spans of their
    timestamps), and the efficiency of that repetition."""
    pair = params["pair"]
    if pair not in PAIRS:
        raise InputError(f"unknown pair {pair!r}; pairs: {', '.join(PAIRS)}", field="pair")
    fam_a, fam_b, two = PAIRS[pair]
    if two and len(gpus) < 2:
        raise InputError("the devices pair needs two VkDevices on one GPU", field="pair")
    ga, gb = gpus[0], gpus[1] if two else gpus[0]
    a, b = _work(ga, fam_a, params), _work(gb, fam_b, params)
    ka, kb = keys(), keys()
    qa, qb = ga.queue(a.queue), gb.queue(b.queue)
    missing = "; ".join(f"no {fam} family: ran on {g.queue(fam).family.kind}"
                        for g, fam in ((ga, fam_a), (gb, fam_b)) if not g.has_dedicated(fam)
                        and fam != "graphics")
    rows: list[dict[str, Any]] = []
    try:
        for rep in range(-warmup, reps):
            t_a = _span([ga.submit(qa, a.record, label="a", key=ka)])
            t_b = _span([gb.submit(qb, b.record, label="b", key=kb)])
            both = _span([ga.submit(qa, a.record, label="a", key=ka),
                          gb.submit(qb, b.record, label="b", key=kb)])
            if rep < 0:
                continue
            rows.append({"device": ga.info.name, "gpu": ga.name, "gpus": 2 if two else 1,
                         "pass": "overlap", **params, "repetition": rep,
                         "queue_a": f"{ga.name}.{qa.family.kind}", "queue_b": f"{gb.name}.{qb.family.kind}",
                         "missing": missing, "alone_a_ns": t_a, "alone_b_ns": t_b,
                         "duration_ns": both, "efficiency": overlap_efficiency(t_a, t_b, both),
                         "bytes": a.bytes + b.bytes})
    finally:
        ga.forget(ka)
        gb.forget(kb)
        a.destroy()
        b.destroy()
    return rows


def _span(subs: Sequence[Any]) -> int:
    """From the first start to the last end of the submissions, on the host clock."""
    stamps = [s.wait().timestamps_ns() for s in subs]
    return max(e for _, e in stamps) - min(s for s, _ in stamps)
