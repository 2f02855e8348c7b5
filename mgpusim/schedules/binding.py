"""Binding a schedule's tasks to the buffers and images a real renderer needs.

Why a shared module: AFR, pipelining, XR and particle offload all move data between GPUs with
the same crossing tasks (:func:`.crossing.cross`): a download into a host staging buffer, an
optional host-to-host copy into the destination's staging buffer, an upload; a device-local
copy when source and destination are one GPU. Each schedule names what its passes write and
read; this module declares those resources and fills in the copies' `src` / `dst` / `params`
the same way for all of them. The simulator ignores all of it.

Conventions the Vulkan runner relies on (docs/runner.md):
- images are RGBA8 colour (+ D16 depth); a copy of an image moves its colour bytes, then its
  depth bytes, so a crossing of `w x h` pixels carries `w * h * (4 + 2 if depth)` bytes;
- a chunk of a chunked copy is a range of whole rows (`params["rows"]` = (first row, rows));
- `params["dst_offset"]` = (x, y) places the moved picture in a larger destination image;
- staging buffers are per crossing piece (one per chunk), with the copy's byte count.
"""
from __future__ import annotations

import dataclasses
from types import MappingProxyType
from typing import Any, Mapping, Sequence

from mgpusim.model.geometry import even_split
from mgpusim.model.tasks import CopyTask, HostCopyTask, Resource, Task

#: Bytes of a colour (RGBA8) and a depth (D16) pixel of the runner's images.
COLOUR_PIXEL_BYTES, DEPTH_PIXEL_BYTES = 4, 2


class Bindings:
    """The resources a schedule declares, collected while its tasks are bound."""

    def __init__(self) -> None:
        self._res: dict[str, Resource] = {}

    def _add(self, res: Resource) -> str:
        old = self._res.get(res.name)
        if old is not None and old != res:
            raise ValueError(f"resource {res.name!r} declared twice, differently: {old} / {res}")
        self._res[res.name] = res
        return res.name

    def image(self, name: str, device: int, width: int, height: int, *, depth: bool = False,
              buffers: int = 1) -> str:
        return self._add(Resource(name, device, "image", width, height, depth, buffers=buffers))

    def buffer(self, name: str, device: int | None, nbytes: int, *, buffers: int = 1,
               host_visible: bool = False, shared_by: tuple[int, ...] = ()) -> str:
        return self._add(Resource(name, device, "buffer", bytes=nbytes, buffers=buffers,
                                  host_visible=host_visible, shared_by=shared_by))

    def resources(self) -> tuple[Resource, ...]:
        return tuple(self._res.values())


def bind_crossing(piece: Sequence[Task], b: Bindings, src: str, dst: str, *, staging: str,
                  buffers: int = 1, params: Mapping[str, Any] | None = None,
                  down: Mapping[str, Any] | None = None,
                  up: Mapping[str, Any] | None = None) -> list[Task]:
    """The tasks of one crossing (as `cross` made them) moving resource `src` to `dst`.

    Through host memory the download writes `gpu{s}.staging.{staging}` and the host copy moves
    it to `gpu{d}.staging.{staging}`; without a host copy one host allocation
    `host.staging.{staging}`, imported by
    both devices, is written and read. `params` (rows, dst_offset, extent) go to the copies
    that touch the images, `down` / `up` only to the download / upload (`images`: several
    images through one buffer). A peer copy is left unbound (the runner refuses it)."""
    region = MappingProxyType(dict(params or {}))
    down_region = MappingProxyType({**region, **(down or {})})
    up_region = MappingProxyType({**region, **(up or {})})
    host_copy = any(isinstance(t, HostCopyTask) for t in piece)
    out: list[Task] = []
    for task in piece:
        if isinstance(task, HostCopyTask):
            s, d = _ends(piece)
            out.append(dataclasses.replace(
                task, src=_staging(b, f"gpu{s}.staging.{staging}", s, task.bytes, buffers),
                dst=_staging(b, f"gpu{d}.staging.{staging}", d, task.bytes, buffers)))
        elif isinstance(task, CopyTask) and task.path == "d2d":
            out.append(dataclasses.replace(task, src=src, dst=dst, params=region))
        elif isinstance(task, CopyTask) and task.path == "d2h":
            s, d = _ends(piece)
            name = (_staging(b, f"gpu{s}.staging.{staging}", s, task.bytes, buffers) if host_copy
                    else _shared(b, f"host.staging.{staging}", (s, d), task.bytes, buffers))
            out.append(dataclasses.replace(task, src=src, dst=name, params=down_region))
        elif isinstance(task, CopyTask) and task.path == "h2d":
            s, d = _ends(piece)
            name = f"gpu{d}.staging.{staging}" if host_copy else f"host.staging.{staging}"
            out.append(dataclasses.replace(task, src=name, dst=dst, params=up_region))
        else:
            out.append(task)
    return out


def _ends(piece: Sequence[Task]) -> tuple[int, int]:
    """(source GPU, destination GPU) of a host-path crossing."""
    down = next(t for t in piece if isinstance(t, CopyTask) and t.path == "d2h")
    up = next(t for t in piece if isinstance(t, CopyTask) and t.path == "h2d")
    return down.queue.device, up.queue.device


def _staging(b: Bindings, name: str, device: int, nbytes: int, buffers: int) -> str:
    return b.buffer(name, device, nbytes, buffers=buffers, host_visible=True)


def _shared(b: Bindings, name: str, devices: tuple[int, int], nbytes: int, buffers: int) -> str:
    return b.buffer(name, None, nbytes, buffers=buffers, host_visible=True, shared_by=devices)


def row_chunks(height: int, chunks: int) -> list[dict[str, Any]]:
    """The copy params of each chunk of an image copy split into `chunks` pieces of whole rows:
    `rows` = (first row, rows), the rows split as :func:`chunk_bytes` splits the bytes (the
    last chunk takes the remainder), so that a chunk carries the bytes the model gives it.
    A chunk needs a row at least: with more chunks than rows every chunk says why the runner
    cannot copy it (`unsupported`); the simulator still runs such a configuration."""
    if chunks > height:
        why = (f"the Vulkan runner copies chunks of whole rows: schedule.chunks = {chunks} is "
               f"more than the image's {height} rows")
        return [{"unsupported": why}] * chunks
    out, first = [], 0
    for rows in even_split(height, chunks):
        out.append({"rows": (first, rows)})
        first += rows
    return out


def chunk_bytes(nbytes: int, height: int, chunks: int) -> list[int]:
    """A copy's bytes in `chunks` pieces: whole rows of an image `height` rows high where the
    bytes are whole rows (the runner copies rows), else equal shares."""
    if height >= chunks and nbytes % height == 0:
        return [rows * (nbytes // height) for rows in even_split(height, chunks)]
    return even_split(nbytes, chunks)
