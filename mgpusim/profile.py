"""Hardware profiles: frozen, validated descriptions of a machine (host, GPUs, links).

Units are in field names: `_gbps` is GB/s (10^9 bytes per second, i.e. bytes per ns),
`_ns` nanoseconds, `_bytes` bytes. A what-if is `dataclasses.replace(profile, ...)`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

from .config import Table, read_toml
from .errors import InputError

#: Per-lane data rate in GB/s after line encoding (8b/10b for gen 1-2, 128b/130b for 3-5,
#: FLIT 242/256 for 6). PCIe 3.0: 8 GT/s * 128/130 / 8 = 0.985 GB/s per lane.
PCIE_LANE_GBPS: Mapping[int, float] = MappingProxyType({
    1: 2.5 * 8 / 10 / 8, 2: 5.0 * 8 / 10 / 8, 3: 8.0 * 128 / 130 / 8,
    4: 16.0 * 128 / 130 / 8, 5: 32.0 * 128 / 130 / 8, 6: 64.0 * 242 / 256 / 8,
})
QUEUE_FAMILIES = ("graphics", "compute", "transfer")
COPY_PATHS = ("d2h", "h2d", "d2d", "p2p")


@dataclass(frozen=True)
class HostProfile:
    """Host memory and the memcpy thread pool used for host-to-host copies."""

    memory_bandwidth_gbps: float
    memcpy_threads: int
    memcpy_thread_gbps: float
    cpu_cores: int
    host_copy_fixed_ns: int = 0
    #: The GPUs are emulated on the host CPU (lavapipe): their passes, copies and the host
    #: copies all share `cpu_cores`.
    gpus_share_cpu: bool = False
    #: Host wake-up before a task whose input comes from another device or the host: a thread
    #: waits on a fence, wakes, then submits (or copies).
    dispatch_ns: int = 0
    #: Host time to record and submit one task, on its queue's submit thread: tasks of one
    #: queue are submitted one after another, a task fed by another device or the host only
    #: after the thread woke (dispatch_ns). Where the GPUs share the CPU it also takes cores.
    submit_ns: int = 0
    #: Lavapipe: the fraction of the cores' time left for work when busy threads want twice the
    #: cores or more (context switches, cache misses); from 1 at as many threads as cores it
    #: falls linearly to this. 1 = perfect sharing.
    oversubscribed_efficiency: float = 1.0


@dataclass(frozen=True)
class LinkProfile:
    """A GPU's PCIe link; bandwidth per direction from generation, lanes and efficiency."""

    pcie_gen: int
    lanes: int
    latency_ns: int
    efficiency: float = 1.0
    h2d_gbps: float | None = None
    d2h_gbps: float | None = None

    def bandwidth_gbps(self, path: str) -> float:
        measured = self.h2d_gbps if path == "h2d" else self.d2h_gbps
        if measured is not None:
            return measured
        return PCIE_LANE_GBPS[self.pcie_gen] * self.lanes * self.efficiency


@dataclass(frozen=True)
class CopyCosts:
    """Per queue family: fixed cost of one copy command and optional per-path rate caps."""

    fixed_ns: int = 0
    caps_gbps: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True)
class PassCost:
    """Linear cost of one pass kind: fixed_ns + sum(ns_per[term] * work[term])."""

    fixed_ns: float
    ns_per: Mapping[str, float]
    #: CPU-emulated GPUs only: the cores this pass keeps busy, measured as the slope of the
    #: process's CPU time on the pass's time. None = the GPU's `cpu_threads`. Why:
    #: lavapipe shades and bins vertices on one thread, so a mesh pass barely gains from more
    #: threads (and two GPUs drawing meshes hardly slow each other down), unlike a fragment pass.
    cores: float | None = None


@dataclass(frozen=True)
class GpuProfile:
    name: str
    memory_bytes: int
    queues: Mapping[str, int]
    link: LinkProfile
    costs: Mapping[str, PassCost]
    copy: Mapping[str, CopyCosts]
    local_copy_gbps: float = 300.0
    #: CPU threads a CPU-emulated GPU renders with (LP_NUM_THREADS); None = all cores.
    cpu_threads: int | None = None
    #: Idle time a queue spends between two of its tasks (switching command buffers, writing
    #: timestamps, signalling fences): not inside any task's own timestamps.
    task_gap_ns: int = 0

    def has_queue(self, family: str, index: int = 0) -> bool:
        return self.queues.get(family, 0) > index


@dataclass(frozen=True)
class PeerLink:
    """A direct GPU-to-GPU link (NVLink); full duplex, one channel per direction."""

    a: int
    b: int
    bandwidth_gbps: float
    latency_ns: int


@dataclass(frozen=True)
class HardwareProfile:
    name: str
    host: HostProfile
    gpus: tuple[GpuProfile, ...]
    peer_links: tuple[PeerLink, ...] = ()
    source: str = ""

    def peer(self, a: int, b: int) -> PeerLink | None:
        for link in self.peer_links:
            if {link.a, link.b} == {a, b}:
                return link
        return None


def load_profile(path: str | Path) -> HardwareProfile:
    """Read and validate a hardware profile TOML file."""
    path = Path(path)
    return parse_profile(read_toml(path), str(path))


def parse_profile(data: dict, file: str) -> HardwareProfile:
    top = Table(data, file)
    name = top.get("name", str)
    top.get("description", str, "")
    top.table("sources", None).rest()  # free-text provenance notes, kept in the file
    host = _parse_host(top.table("host"))
    gpus: list[GpuProfile] = []
    for t in top.tables("gpus"):
        count = t.get("count", int, 1, minimum=1)
        gpus.extend([_parse_gpu(t)] * count)
    peers = tuple(_parse_peer(t, len(gpus)) for t in (top.tables("peer_links") if top.has("peer_links") else []))
    top.finish()
    return HardwareProfile(name=name, host=host, gpus=tuple(gpus), peer_links=peers, source=file)


def _parse_host(t: Table) -> HostProfile:
    host = HostProfile(
        memory_bandwidth_gbps=t.get("memory_bandwidth_gbps", float, above=0),
        memcpy_threads=t.get("memcpy_threads", int, minimum=1),
        memcpy_thread_gbps=t.get("memcpy_thread_gbps", float, above=0),
        cpu_cores=t.get("cpu_cores", int, minimum=1),
        host_copy_fixed_ns=t.get("host_copy_fixed_ns", int, 0, minimum=0),
        gpus_share_cpu=t.get("gpus_share_cpu", bool, False),
        dispatch_ns=t.get("dispatch_ns", int, 0, minimum=0),
        submit_ns=t.get("submit_ns", int, 0, minimum=0),
        oversubscribed_efficiency=t.get("oversubscribed_efficiency", float, 1.0, above=0),
    )
    _check_host(t, host)
    t.finish()
    return host


def _check_host(t: Table, host: HostProfile) -> None:
    if host.oversubscribed_efficiency > 1:
        raise t.error("oversubscribed_efficiency", f"must be <= 1, got {host.oversubscribed_efficiency}")


def _parse_gpu(t: Table) -> GpuProfile:
    queues_t = t.table("queues")
    queues = {fam: queues_t.get(fam, int, 0, minimum=0) for fam in QUEUE_FAMILIES}
    queues_t.finish()
    if queues["graphics"] < 1:
        raise queues_t.error("graphics", "a GPU needs at least one graphics queue")
    gpu = GpuProfile(
        name=t.get("name", str),
        memory_bytes=t.get("memory_bytes", int, minimum=1),
        queues=MappingProxyType(queues),
        link=_parse_link(t.table("link")),
        costs=_parse_costs(t.table("costs")),
        copy=_parse_copy(t.table("copy", None)),
        local_copy_gbps=t.get("local_copy_gbps", float, 300.0, above=0),
        cpu_threads=t.get("cpu_threads", int, None, minimum=1),
        task_gap_ns=t.get("task_gap_ns", int, 0, minimum=0),
    )
    t.finish()
    return gpu


def _parse_link(t: Table) -> LinkProfile:
    link = LinkProfile(
        pcie_gen=t.get("pcie_gen", int, choices=PCIE_LANE_GBPS.keys()),
        lanes=t.get("lanes", int, choices=(1, 2, 4, 8, 16, 32)),
        latency_ns=t.get("latency_ns", int, minimum=0),
        efficiency=t.get("efficiency", float, 1.0, above=0),
        h2d_gbps=t.get("h2d_gbps", float, None, above=0),
        d2h_gbps=t.get("d2h_gbps", float, None, above=0),
    )
    if link.efficiency > 1:
        raise t.error("efficiency", f"must be <= 1, got {link.efficiency}")
    t.finish()
    return link


def _parse_costs(t: Table) -> Mapping[str, PassCost]:
    costs: dict[str, PassCost] = {}
    for kind in list(t.data):
        kt = t.table(kind)
        fixed = kt.get("fixed_ns", float, 0.0, minimum=0)
        cores = kt.get("cores", float, None, minimum=0.01)
        ns_per: dict[str, float] = {}
        for key in list(kt.rest()):
            if not key.startswith("ns_per_"):
                raise kt.error(key, "cost coefficients are named fixed_ns, ns_per_<work term> "
                                    "or cores")
            ns_per[key.removeprefix("ns_per_")] = kt.get(key, float, minimum=0)
        kt.finish()
        costs[kind] = PassCost(fixed, MappingProxyType(ns_per), cores)
    return MappingProxyType(costs)


def _parse_copy(t: Table) -> Mapping[str, CopyCosts]:
    out: dict[str, CopyCosts] = {}
    for fam in list(t.data):
        if fam not in QUEUE_FAMILIES:
            raise t.error(fam, f"unknown queue family (expected one of {list(QUEUE_FAMILIES)})")
        ft = t.table(fam)
        fixed = ft.get("fixed_ns", int, 0, minimum=0)
        caps = {p: ft.get(f"{p}_gbps", float, above=0) for p in COPY_PATHS if ft.has(f"{p}_gbps")}
        ft.finish()
        out[fam] = CopyCosts(fixed, MappingProxyType(caps))
    return MappingProxyType(out)


def _parse_peer(t: Table, n_gpus: int) -> PeerLink:
    ends = t.get("gpus", list)
    if len(ends) != 2 or not all(isinstance(g, int) and 0 <= g < n_gpus for g in ends) or ends[0] == ends[1]:
        raise t.error("gpus", f"expected two different GPU indices in 0..{n_gpus - 1}, got {ends!r}")
    link = PeerLink(ends[0], ends[1], t.get("bandwidth_gbps", float, above=0), t.get("latency_ns", int, minimum=0))
    t.finish()
    return link


def require_gpus(profile: HardwareProfile, n: int, file: str | None = None) -> None:
    if n > len(profile.gpus):
        raise InputError(f"asks for {n} GPUs but profile {profile.name!r} has {len(profile.gpus)}",
                         file=file, field="schedule.gpus")
