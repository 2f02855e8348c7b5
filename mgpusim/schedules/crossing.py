"""Moving a buffer from one GPU to another, as tasks the Vulkan runner can execute.

Unlinked explicit multi-GPU has no shared device memory, so a buffer crosses GPUs either
through host memory (the source's copy engine writes a host staging buffer, optionally a
host-to-host memcpy moves it to the destination's staging buffer, the destination's copy
engine reads it) or, where the profile has one, over a peer link (NVLink: one copy).
Shared by the AFR, pipelining and XR schedules so they route copies the same way.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from mgpusim.model.errors import InputError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.tasks import CopyPath, CopyTask, Dep, HostCopyTask, QueueRef, Task
from mgpusim.schedules.base import queue_or_graphics
from mgpusim.schedules.registry import Option

#: How buffers cross GPUs (the `path` option of every schedule that moves them).
PATHS = ("auto", "host", "peer", "group")

COPY_OPTIONS = {
    "copy_queue": Option(str, "transfer", "queue that records cross-GPU copies: 'transfer' (the copy "
                         "engine, or graphics where the GPU has none) or 'graphics'",
                         choices=("transfer", "graphics")),
    "path": Option(str, "auto", "how buffers cross GPUs: 'host' (through host memory), 'peer' (a "
                   "peer link, which the profile must have), 'group' (GPU to GPU over PCIe in a "
                   "device group / linked-node adapter) or 'auto' (peer if present)",
                   choices=PATHS),
    "host_copy": Option(bool, False, "add a host-to-host memcpy between the two staging buffers "
                        "(Vulkan memory objects belong to one device); false: one host allocation "
                        "imported by both devices"),
}


@dataclass(frozen=True)
class Route:
    """How copies are placed: queue policy, path and whether a host memcpy is needed."""

    copy_queue: str = "transfer"
    path: str = "auto"
    host_copy: bool = False

    @classmethod
    def from_options(cls, opt: Callable[[str], Any]) -> "Route":
        return cls(opt("copy_queue"), opt("path"), opt("host_copy"))


def copy_queue(profile: HardwareProfile, device: int, policy: str) -> QueueRef:
    """The queue a device records copies on under `policy` ('transfer' falls back to graphics)."""
    if policy == "graphics":
        return QueueRef(device, "graphics")
    return queue_or_graphics(profile, device, "transfer")


def use_peer(profile: HardwareProfile, src: int, dst: int, route: Route) -> bool:
    """True if the buffer crosses over a peer link; 'peer' without a link is an input error."""
    has = profile.peer(src, dst) is not None
    if route.path == "peer" and not has:
        raise InputError(f"no peer link between gpu{src} and gpu{dst} in profile {profile.name!r}",
                         field="schedule.path")
    return has and route.path != "host"


def cross(prefix: str, profile: HardwareProfile, src: int, dst: int, nbytes: int,
          deps: tuple[Dep, ...], route: Route, *, dst_deps: tuple[Dep, ...] = (),
          pull: bool = False, skip: bool = False, through_host: bool = False) -> list[Task]:
    """Tasks moving `nbytes` from `src` to `dst`; the last task's end means "arrived".

    `deps` gate the first task (the data is ready, the source buffer may be read); `dst_deps`
    gate the task that writes the destination (its buffer is free). A peer copy is recorded
    on the destination's queue when `pull` (it reads peer memory) else on the source's.
    `skip` marks the tasks as followers of a skippable task (see PassTask.skip_if_busy).
    `through_host`: a buffer that stays on one GPU still goes down to host memory and back up
    (an engine that moves it through the CPU on one GPU as it does between two).
    """
    if src == dst and not through_host:
        q = copy_queue(profile, src, route.copy_queue)
        return [CopyTask(f"{prefix}.d2d", "d2d", q, "d2d", nbytes, deps + dst_deps, skip_if_busy=skip)]
    if src != dst and (route.path == "group" or use_peer(profile, src, dst, route)):
        dev, peer = (dst, src) if pull else (src, dst)
        q = copy_queue(profile, dev, route.copy_queue)
        path: CopyPath = "group" if route.path == "group" else "p2p"
        return [CopyTask(f"{prefix}.{path}", "p2p", q, path, nbytes, deps + dst_deps, peer=peer,
                         skip_if_busy=skip, pull=pull)]
    d2h = CopyTask(f"{prefix}.d2h", "d2h", copy_queue(profile, src, route.copy_queue), "d2h",
                   nbytes, deps, skip_if_busy=skip)
    out: list[Task] = [d2h]
    if route.host_copy:
        out.append(HostCopyTask(f"{prefix}.host", "host_copy", nbytes, (Dep(d2h.name),),
                                skip_if_busy=skip))
    out.append(CopyTask(f"{prefix}.h2d", "h2d", copy_queue(profile, dst, route.copy_queue), "h2d",
                        nbytes, (Dep(out[-1].name),) + dst_deps, skip_if_busy=skip))
    return out
