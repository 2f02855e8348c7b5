"""What a whole-frame scene pass reads and writes on the Vulkan runner.

Why shared: AFR, frame pipelining and particle offload run the scene's passes full-frame on
one GPU each; they bind those passes alike. Every pass renders into an image of its own
(`{prefix}{pass name}`, with depth for a mesh), so a later `filter` pass can sample it; a
`filter` with `inputs = k` samples the outputs of the k passes before it in the scene, the
nearest last (its accumulating input). One input more than the passes before it (`inputs =
index + 1`, a temporal filter such as TAA) is its own output of the previous frame on the same
GPU, sampled last: what a one-GPU AFR temporal pass samples and what a frame import lists as a
pass reading itself; the image it renders into is then double-buffered. Schedules replace inputs
where the data comes from elsewhere: another GPU's copy (pipelining), the previous frame of
another GPU (AFR's temporal pass on N GPUs). The model's work terms count `inputs` either way.
"""
from __future__ import annotations

import dataclasses
from types import MappingProxyType
from typing import Any, Callable, Mapping, Sequence

from mgpusim.model.scene import PassSpec, Scene
from mgpusim.model.tasks import PassTask
from mgpusim.schedules.binding import Bindings


def pass_image(b: Bindings, name: str, device: int, scene: Scene, spec: PassSpec,
               buffers: int = 1) -> str:
    """The image a full-frame pass renders into."""
    return b.image(name, device, scene.width, scene.height, depth=spec.kind == "mesh",
                   buffers=buffers)


def frame_params(spec: PassSpec, scene: Scene, **extra: Any) -> Mapping[str, Any]:
    """The runner's knobs of a full-frame pass: the frame, the rectangle (all of it), the
    pass's own parameters (iterations, triangles: the whole mesh)."""
    w, h = scene.width, scene.height
    params: dict[str, Any] = {"frame": (w, h), "rect": (0, 0, w, h), "origin": (0, 0),
                              "clear": True, **spec.params, **spec.options}
    if "triangles" in spec.params:
        total = int(spec.params["triangles"])
        params.update(triangles=total, first=0, count=total)
    if "iterations" in spec.params:
        params["iterations"] = int(spec.params["iterations"])
    params.update(simulated_only(spec))
    params.update(extra)
    return MappingProxyType(params)


def simulated_only(spec: PassSpec) -> dict[str, str]:
    """`{"unsupported": why}` for a pass whose parameters the Vulkan runner's pass library
    does not draw (a mesh's `texture_bytes`: its passes sample no textures), else {}."""
    if "texture_bytes" in spec.params:
        return {"unsupported": f"pass {spec.name!r}: texture_bytes is simulated only (the "
                               "runner's meshes sample no textures)"}
    return {}


def filter_sources(passes: Sequence[PassSpec], index: int) -> list[str] | str:
    """Names of the passes a filter at `index` samples (the `inputs` before it, nearest last;
    with one input more than the passes before it, its own name last: its output of the
    previous frame on the same GPU), or why it cannot be run."""
    spec = passes[index]
    k = int(spec.param("inputs", 1))
    if not 1 <= k <= index + 1:
        return (f"filter pass {spec.name!r} samples the {k} passes before it, but {index} "
                f"come before it (1 to 4 inputs; one more than the passes before it samples "
                f"its own output of the previous frame)")
    if k == index + 1:
        return [p.name for p in passes[:index]] + [spec.name]
    return [p.name for p in passes[index - k:index]]


def reads_own_output(passes: Sequence[PassSpec], index: int) -> bool:
    """Whether pass `index` is a filter that samples its own previous output (a history): the
    image it renders into needs two buffered copies, one written while the other is read."""
    spec = passes[index]
    return spec.kind == "filter" and int(spec.param("inputs", 1)) == index + 1


#: What a pass samples, in the shape `bind_full_frame` takes: (its images, their frame
#: offsets); ((), ()) for a pass that samples nothing; (why, ()) for a filter the runner
#: cannot run, `why` saying so.
Reads = tuple[Sequence[str] | str, Sequence[int]]


def filter_reads(passes: Sequence[PassSpec], index: int,
                 image_of: Callable[[str], str]) -> Reads:
    """What pass `index` samples: a filter, `image_of(name)` of each source, its own image at
    offset -1 (the previous frame's output); any other pass, nothing. One shape for all three
    outcomes, so that a caller passes it on (`*filter_reads(...)`) without looking inside."""
    if passes[index].kind != "filter":
        return (), ()
    sources = filter_sources(passes, index)
    if isinstance(sources, str):
        return sources, ()
    own = passes[index].name
    return ([image_of(s) for s in sources],
            [-1 if s == own and n == len(sources) - 1 else 0 for n, s in enumerate(sources)])


def read_params(reads: Sequence[str] | str,
                read_offsets: Sequence[int] = ()) -> tuple[tuple[str, ...], dict[str, Any]]:
    """The images a pass samples and the runner's knobs that say how: `read_offsets` (the
    current frame unless given), or `unsupported` when `reads` is why it cannot run. Shared by
    the full-frame and the tiled (five-step) bindings, which put the knobs in different
    places."""
    if isinstance(reads, str):
        return (), {"unsupported": reads}
    if not reads:
        return (), {}
    return tuple(reads), {"read_offsets": tuple(read_offsets) or (0,) * len(reads)}


def bind_full_frame(task: PassTask, spec: PassSpec, scene: Scene, target: str,
                    reads: Sequence[str] | str = (), read_offsets: Sequence[int] = ()) -> PassTask:
    """`task` rendering `spec` full-frame into `target`, sampling `reads` (a filter); a string
    in `reads` is why the runner cannot run it."""
    images, extra = read_params(reads, read_offsets)
    return dataclasses.replace(task, reads=images, writes=(target,),
                               params=frame_params(spec, scene, **extra))
