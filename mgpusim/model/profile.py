"""Hardware profiles: frozen, validated descriptions of a machine (host, GPUs, links).

Units are in field names: `_gbps` is GB/s (10^9 bytes per second, i.e. bytes per ns),
`_ns` nanoseconds, `_bytes` bytes. A what-if is `dataclasses.replace(profile, ...)`.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, TypeVar

from mgpusim.model import limits as L
from mgpusim.model.errors import InputError
from mgpusim.model.overrides import set_dotted
from mgpusim.model.toml_checks import Table, did_you_mean, read_toml
from mgpusim.model.work_terms import WORK_TERMS, work_terms

_T = TypeVar("_T")

#: Per-lane data rate in GB/s after line encoding (8b/10b for gen 1-2, 128b/130b for 3-5,
#: FLIT 242/256 for 6). PCIe 3.0: 8 GT/s * 128/130 / 8 = 0.985 GB/s per lane.
PCIE_LANE_GBPS: Mapping[int, float] = MappingProxyType({
    1: 2.5 * 8 / 10 / 8, 2: 5.0 * 8 / 10 / 8, 3: 8.0 * 128 / 130 / 8,
    4: 16.0 * 128 / 130 / 8, 5: 32.0 * 128 / 130 / 8, 6: 64.0 * 242 / 256 / 8,
})
PCIE_LANES = (1, 2, 4, 8, 16, 32)
QUEUE_FAMILIES = ("graphics", "compute", "transfer")
COPY_PATHS = ("d2h", "h2d", "d2d", "p2p")
#: Pairs of work on one physical GPU whose overlap efficiency a profile can give
#: (`[gpus.queue_overlap]`): the queue families of one VkDevice, two queues of one family, and
#: two passes of different logical GPUs (VkDevices) on one physical GPU.
OVERLAP_PAIRS = ("graphics_compute", "graphics_transfer", "compute_transfer", "same_family", "devices")
#: Unset pairs: queues of one device overlap perfectly (each runs at full speed, as when every
#: queue was an independent server); two VkDevices on one GPU take turns (time slicing).
OVERLAP_DEFAULTS: Mapping[str, float] = MappingProxyType(
    {"graphics_compute": 2.0, "graphics_transfer": 2.0, "compute_transfer": 2.0, "same_family": 2.0,
     "devices": 1.0})


#: The busy_wake effect's window: a pass is "young" for this long after it starts (a copy's
#: thread woken later finds the pass's threads spread over the cores; measured on lavapipe).
BUSY_WAKE_WINDOW_NS = 1_000_000


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
    #: Latency (not CPU work) from the end of a host copy's input on a device to the copy's
    #: start, when the host-copy thread was idle: its fence wait returns, it wakes, and hands the
    #: parts to the memcpy threads, which wake too. Measured on lavapipe's runs (0.15-0.4 ms);
    #: it comes before `dispatch_ns`.
    host_copy_wake_ns: int = 0
    #: Host threads woken by inputs take turns, one after another (FIFO), each for its
    #: `dispatch_ns`: the mgpusim runner's threads run Python under one interpreter lock.
    #: None: where the GPUs share the CPU (lavapipe, where it was found and measured), not on
    #: GPUs of their own (a native engine's threads wake in parallel); a what-if either way.
    serial_dispatch: bool | None = None
    #: Host time to record and submit one task, on its queue's submit thread: tasks of one
    #: queue are submitted one after another, a task fed by another device or the host only
    #: after the thread woke (dispatch_ns). Where the GPUs share the CPU it also takes cores.
    submit_ns: int = 0
    #: The runner's threads on GPUs of their own share one Python interpreter: a woken thread's
    #: `dispatch_ns` and every task's `submit_ns` (recording, submitting and reaping it) are
    #: one core's time on one interpreter, shared by whoever runs Python at that moment. The
    #: more tasks a frame hands between threads, the later each hand-off. Measured with
    #: tools/probes/h200_x4/interpreter_probe.py: on 4x H200 a woken thread waited a median
    #: 0.26 ms in light 4-GPU sort-first frames and nothing in AFR. A native engine's threads
    #: do not share one: a what-if either way. Not where the GPUs share the CPU (lavapipe: the
    #: cores are the shared resource there, `serial_dispatch` its turns).
    shared_interpreter: bool = False
    #: Lavapipe: the fraction of the cores' time left for work when busy threads of different
    #: work want twice the cores or more (context switches, each evicting the other's caches);
    #: from 1 at as many threads as cores it falls linearly to this. 1 = perfect sharing.
    #: Passes of one kind alone together lose nothing: two GPUs' fragment loops at once take
    #: twice as long, while a filter beside a fragment loop was slowed more than their cores say.
    oversubscribed_efficiency: float = 1.0
    #: Lavapipe: the share of each pass's `cpu_overhead_ns` that competes for the cores (the
    #: part of the driver's work outside the pass that does not overlap the pass itself); the
    #: calibration's grid search picks it on the calibration runs.
    cpu_overhead_scale: float = 1.0
    #: Lavapipe (the busy_wake effect): of the copies about to start within
    #: `busy_wake_window_ns` of another GPU's core-filling pass starting, counted once per
    #: (pass, GPU) pair, the share whose woken thread waits behind that pass's threads while a
    #: core idles, `busy_wake_ns` (or until the pass is done). Measured on the calibration
    #: runs' traces; 0 turns it off.
    busy_wake_share: float = 0.0
    busy_wake_ns: int = 0
    busy_wake_window_ns: int = BUSY_WAKE_WINDOW_NS
    #: Host time to start (and later join) one application thread: an engine that starts its
    #: worker threads every frame (std::async) pays it on the thread that starts them (the
    #: host_frame_work effect; CPU tasks say how many threads they start).
    thread_start_ns: int = 0
    #: Host time to record and submit one command buffer on an application thread (the
    #: host_frame_work effect; CPU tasks say how many they record).
    record_ns: int = 0
    #: One memcpy thread's speed when it reads host-visible memory that is not cached (a
    #: write-combined, HOST_COHERENT staging buffer mapped for the CPU: every load goes to
    #: memory; the uncached_reads effect, for host copies whose source is such memory).
    #: 0: such reads are as fast as cached ones.
    uncached_read_gbps: float = 0.0
    #: What the host side of PCIe (root complex, host memory) takes in one direction from all
    #: the GPUs' links at once, GB/s (the host_pcie effect: every device-to-host or
    #: host-to-device copy then crosses its GPU's link and this shared channel). None: each
    #: GPU's link is its own, however many copy at once.
    pcie_d2h_gbps: float | None = None
    pcie_h2d_gbps: float | None = None

    def pcie_gbps(self, path: str) -> float | None:
        """The host capacity of a PCIe direction ("d2h" or "h2d"; None for any other path)."""
        return {"d2h": self.pcie_d2h_gbps, "h2d": self.pcie_h2d_gbps}.get(path)


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
    #: CPU-emulated GPUs only: CPU time a pass costs outside its own timestamps (the driver's
    #: threads setting it up and finishing it; the intercept of the CPU-time fit), one core's
    #: work on the shared cores that nobody waits on. Why: it takes cores from whatever else
    #: runs, so small passes of several GPUs at once slow each other more than their `cores`
    #: alone say.
    cpu_overhead_ns: float = 0.0
    #: CPU-emulated GPUs only: `cores` was measured as the slowdown of two passes at once, so
    #: the pass shares the cores exactly as `cores` says and takes no part in the host's
    #: `oversubscribed_efficiency` loss, even beside other work. Why: a mesh's slowdown two at
    #: once (1.4-1.5x) is more than its CPU time says (1.2 cores), and that measured slowdown
    #: already holds what the two lose to each other.
    cores_from_pairs: bool = False
    #: The calibration's standard errors of `fixed_ns` ("fixed_ns") and of each `ns_per` term
    #: (by term): simulate carries them into results as a band (empty: no band).
    stderr: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    #: CPU-emulated GPUs only: the cores the work of each listed term keeps busy, where it is
    #: not `cores` (which then holds for the fixed part and the other terms); a pass keeps busy
    #: the mean of its parts' cores weighted by their time (:meth:`cores_of`). Why: llvmpipe
    #: shades, clips, culls and bins a draw's triangles on the thread that runs the command
    #: buffer and rasterizes on its rasterizer threads, so a mesh whose triangles are mostly
    #: culled (vmgpu's sphere) keeps fewer cores busy than our torus, every triangle
    #: rasterized (a main job: 1.31 cores for the triangles' part, 1.49 for the rest): one
    #: `cores` per kind cannot be both.
    term_cores: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    def cores_of(self, work: Mapping[str, float]) -> float | None:
        """The cores a pass of this cost with `work` keeps busy: `cores`, or with `term_cores`
        the time-weighted mean of its parts' (None: not measured)."""
        if self.cores is None or not self.term_cores:
            return self.cores
        rest, listed, busy = self.fixed_ns, 0.0, 0.0
        for term, amount in work.items():
            ns = self.ns_per.get(term, 0.0) * amount
            cores = self.term_cores.get(term)
            if cores is None:
                rest += ns
            else:
                listed, busy = listed + ns, busy + cores * ns
        total = rest + listed
        return self.cores if total <= 0 else (busy + self.cores * rest) / total

    def shifted(self, sigmas: float) -> "PassCost":
        """The cost with every coefficient moved by `sigmas` standard errors (kept >= 0)."""
        move = lambda key, v: max(0.0, v + sigmas * self.stderr.get(key, 0.0))  # noqa: E731
        return replace(self, fixed_ns=move("fixed_ns", self.fixed_ns),
                       ns_per=MappingProxyType({t: move(t, v) for t, v in self.ns_per.items()}))


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
    #: What-if speed factor: every pass's time is divided by it (1.5 = a GPU 1.5x faster);
    #: copies and links keep their own rates.
    speed: float = 1.0
    #: The physical GPU this (logical) GPU runs on; GPUs with the same value share it (several
    #: VkDevices on one GPU). None = a physical GPU of its own (its index).
    physical: int | None = None
    #: Overlap efficiency of two pieces of work at once on this physical GPU, per pair
    #: (OVERLAP_PAIRS): their throughput together over one alone, from 1 (no gain: back to back)
    #: to 2 (each at full speed). Empty: none given (every pair at its default).
    queue_overlap: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    #: Per pass kind, the efficiencies of the pairs that pass is in where they differ from
    #: `queue_overlap` (`[gpus.queue_overlap.<kind>]`): how much two pieces of work slow each
    #: other depends on what they are bound by (a blending draw suffers from a copy's memory
    #: traffic; an arithmetic-bound loop hardly does).
    overlap_by_kind: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))

    def overlap(self, pair: str, kinds: tuple[str, ...] = ()) -> float:
        """The overlap efficiency of `pair` between work of `kinds` (pass kinds; "copy" for a
        copy): the lowest a kind's own table gives, else the GPU's, else the default."""
        own = [self.overlap_by_kind[k][pair] for k in kinds
               if k in self.overlap_by_kind and pair in self.overlap_by_kind[k]]
        return min(own) if own else self.queue_overlap.get(pair, OVERLAP_DEFAULTS[pair])

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
class CalibratedOn:
    """The machine a profile was calibrated on (`[sources.machine]`, written by a calibration):
    its CPU model and usable CPUs, its GPUs' device name and driver. Why: a profile's accuracy
    holds on the machine it was measured on; a comparison with runs of another machine says so."""

    cpu: str
    cpus: int
    device: str
    driver: str

    def differences(self, other: "CalibratedOn") -> dict[str, tuple[Any, Any]]:
        """field -> (this machine's value, the other's), where they differ."""
        return {f: (getattr(self, f), getattr(other, f)) for f in ("cpu", "cpus", "device", "driver")
                if getattr(self, f) != getattr(other, f)}


@dataclass(frozen=True)
class HardwareProfile:
    name: str
    host: HostProfile
    gpus: tuple[GpuProfile, ...]
    peer_links: tuple[PeerLink, ...] = ()
    source: str = ""
    calibrated_on: CalibratedOn | None = None

    def physical_of(self, gpu: int) -> int:
        """The physical GPU logical GPU `gpu` runs on (`physical`, default its own index)."""
        phys = self.gpus[gpu].physical
        return gpu if phys is None else phys

    def shares_physical(self) -> bool:
        """Whether two logical GPUs run on one physical GPU."""
        return len({self.physical_of(i) for i in range(len(self.gpus))}) < len(self.gpus)

    def peer(self, a: int, b: int) -> PeerLink | None:
        for link in self.peer_links:
            if {link.a, link.b} == {a, b}:
                return link
        return None


def links_as_rates(profile: HardwareProfile) -> HardwareProfile:
    """`profile` with every GPU's link given as what the model reads of it: its rate each
    way and its latency (:meth:`LinkProfile.bandwidth_gbps`, `latency_ns`), not the
    generation and lanes that give the rate. Two profiles equal so differ in nothing the model
    reads (PCIe 3.0 x16 and 4.0 x8 are one link): `mgpusim advise` runs their options once."""
    def rates(link: LinkProfile) -> LinkProfile:
        return LinkProfile(pcie_gen=0, lanes=0, latency_ns=link.latency_ns,
                           h2d_gbps=link.bandwidth_gbps("h2d"), d2h_gbps=link.bandwidth_gbps("d2h"))
    return replace(profile, gpus=tuple(replace(g, link=rates(g.link)) for g in profile.gpus))


def load_profile(path: str | Path, overrides: Mapping[str, object] | None = None) -> HardwareProfile:
    """Read and validate a hardware profile TOML file; `overrides` (dotted keys relative to the
    profile, e.g. ``gpus.0.link.pcie_gen``) change the raw file first (hardware what-ifs), so
    they are checked exactly like values written in it."""
    path = Path(path)
    data = read_toml(path)
    if overrides:
        data = apply_profile_overrides(data, overrides, str(path))
    return parse_profile(data, str(path))


def apply_profile_overrides(data: dict, overrides: Mapping[str, object], file: str) -> dict:
    """A copy of the raw profile with `overrides` set (keys relative to the profile).

    Where a GPU table's link gives measured bandwidths (h2d_gbps / d2h_gbps) and an override
    changes its pcie_gen or lanes, the measured bandwidths scale with the nominal rate (PCIe 5
    x16 over PCIe 4 x16 = 2x), so the what-if keeps the measured efficiency instead of being
    silently ignored; an override of the bandwidth itself wins."""
    data = copy.deepcopy(data)
    before = _nominal_rates(data)
    for key, value in overrides.items():
        set_dotted(data, key, value, file, prefix="profile.")
    after = _nominal_rates(data)
    for i, old in before.items():
        new = after.get(i)
        if new is None or new == old:
            continue
        link = data["gpus"][i]["link"]  # a table: _nominal_rates found a rate in it
        for key in ("h2d_gbps", "d2h_gbps"):
            value = link.get(key)
            if _is_number(value) and not _overridden(f"gpus.{i}.link.{key}", overrides):
                link[key] = value * new / old
    return data


def _nominal_rates(data: dict) -> dict[int, float]:
    """GB/s of lanes x per-lane rate of each [[gpus]] table's link (where gen and lanes are valid)."""
    out = {}
    gpus = data.get("gpus")
    for i, gpu in enumerate(gpus if isinstance(gpus, list) else []):
        link = gpu.get("link") if isinstance(gpu, dict) else None
        if not isinstance(link, dict):
            continue
        gen = link.get("pcie_gen")
        if isinstance(gen, int) and gen in PCIE_LANE_GBPS and link.get("lanes") in PCIE_LANES:
            out[i] = PCIE_LANE_GBPS[link["pcie_gen"]] * link["lanes"]
    return out


def _is_number(value: object) -> bool:
    """A positive number that is finite as a float (parse_profile reports anything else)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return 0 < float(value) < math.inf
    except OverflowError:
        return False


def _overridden(path: str, overrides: Mapping[str, object]) -> bool:
    """Whether an override sets `path` or a table above it (``gpus.*`` counts for every entry)."""
    parts = path.split(".")
    for key in overrides:
        kparts = key.split(".")
        if len(kparts) <= len(parts) and all(k in (p, "*") for k, p in zip(kparts, parts)):
            return True
    return False


def _calibrated_on(t: Table) -> CalibratedOn:
    machine = CalibratedOn(t.get("cpu", str), t.get("cpus", int, minimum=1), t.get("device", str),
                           t.get("driver", str))
    t.finish()
    return machine


def parse_profile(data: dict, file: str) -> HardwareProfile:
    top = Table(data, file)
    name = top.get("name", str)
    top.get("description", str, "")
    sources = top.table("sources", None)
    calibrated_on = _calibrated_on(sources.table("machine")) if sources.has("machine") else None
    sources.rest()  # free-text provenance notes, kept in the file
    host = _parse_host(top.table("host"))
    gpus: list[GpuProfile] = []
    tables: list[str] = []  # each GPU's [[gpus]] table, for messages
    for t in top.tables("gpus"):
        count = t.get("count", int, 1, minimum=1, maximum=L.MAX_GPUS, why=L.WHY_ALLOC)
        if len(gpus) + count > L.MAX_GPUS:
            raise t.error("count", f"the profile would have {len(gpus) + count} GPUs, more than "
                                   f"{L.MAX_GPUS} ({L.WHY_ALLOC})")
        gpus.extend([_parse_gpu(t)] * count)
        tables.extend([t.path] * count)
    gpus = _resize(gpus, top.get("gpu_count", int, len(gpus), minimum=1, maximum=L.MAX_GPUS,
                                 why=L.WHY_ALLOC))
    peers = tuple(_parse_peer(t, len(gpus)) for t in (top.tables("peer_links") if top.has("peer_links") else []))
    if top.has("peer_mesh"):
        peers = _peer_mesh(top.table("peer_mesh"), len(gpus), peers)
    top.finish()
    profile = HardwareProfile(name=name, host=host, gpus=tuple(gpus), peer_links=peers, source=file,
                              calibrated_on=calibrated_on)
    _check_physical(profile, _resize(tables, len(profile.gpus)), file)
    return profile


def _check_physical(profile: HardwareProfile, tables: list[str], file: str) -> None:
    """Logical GPUs on one physical GPU describe it alike: one `queue_overlap` per physical GPU
    (`tables`: each GPU's [[gpus]] table, named in the message)."""
    first: dict[int, int] = {}
    for i, gpu in enumerate(profile.gpus):
        j = first.setdefault(profile.physical_of(i), i)
        other = profile.gpus[j]
        if (dict(gpu.queue_overlap), {k: dict(v) for k, v in gpu.overlap_by_kind.items()}) != \
                (dict(other.queue_overlap), {k: dict(v) for k, v in other.overlap_by_kind.items()}):
            raise InputError(f"GPUs {j} and {i} run on physical GPU {profile.physical_of(i)} but give "
                             "different queue_overlap tables (one physical GPU has one)", file=file,
                             field=f"{tables[i]}.queue_overlap")


def _resize(gpus: list[_T], count: int) -> list[_T]:
    """`gpu_count` (a what-if): the first `count` GPUs, the last one repeated to reach it."""
    return (gpus + [gpus[-1]] * count)[:count]


def _parse_host(t: Table) -> HostProfile:
    host = HostProfile(
        memory_bandwidth_gbps=_gbps(t, "memory_bandwidth_gbps"),
        memcpy_threads=t.get("memcpy_threads", int, minimum=1, maximum=L.MAX_THREADS, why=L.WHY_ALLOC),
        memcpy_thread_gbps=_gbps(t, "memcpy_thread_gbps"),
        cpu_cores=t.get("cpu_cores", int, minimum=1, maximum=L.MAX_THREADS, why=L.WHY_ALLOC),
        host_copy_fixed_ns=_ns(t, "host_copy_fixed_ns", 0),
        gpus_share_cpu=t.get("gpus_share_cpu", bool, False),
        dispatch_ns=_ns(t, "dispatch_ns", 0),
        host_copy_wake_ns=_ns(t, "host_copy_wake_ns", 0),
        serial_dispatch=t.get("serial_dispatch", bool, None) if t.has("serial_dispatch") else None,
        submit_ns=_ns(t, "submit_ns", 0),
        shared_interpreter=t.get("shared_interpreter", bool, False),
        oversubscribed_efficiency=t.get("oversubscribed_efficiency", float, 1.0, above=0),
        cpu_overhead_scale=t.get("cpu_overhead_scale", float, 1.0, minimum=0, maximum=1),
        busy_wake_share=t.get("busy_wake_share", float, 0.0, minimum=0, maximum=1),
        busy_wake_ns=_ns(t, "busy_wake_ns", 0),
        busy_wake_window_ns=_ns(t, "busy_wake_window_ns", BUSY_WAKE_WINDOW_NS),
        thread_start_ns=_ns(t, "thread_start_ns", 0),
        record_ns=_ns(t, "record_ns", 0),
        uncached_read_gbps=_gbps(t, "uncached_read_gbps", 0.0) if t.has("uncached_read_gbps") else 0.0,
        pcie_d2h_gbps=_gbps(t, "pcie_d2h_gbps", None),
        pcie_h2d_gbps=_gbps(t, "pcie_h2d_gbps", None),
    )
    _check_host(t, host)
    t.finish()
    return host


def _check_host(t: Table, host: HostProfile) -> None:
    if host.oversubscribed_efficiency > 1:
        raise t.error("oversubscribed_efficiency", f"must be <= 1, got {host.oversubscribed_efficiency}")


def _parse_gpu(t: Table) -> GpuProfile:
    queues_t = t.table("queues")
    queues = {fam: queues_t.get(fam, int, 0, minimum=0, maximum=L.MAX_QUEUES, why=L.WHY_ALLOC)
              for fam in QUEUE_FAMILIES}
    queues_t.finish()
    if queues["graphics"] < 1:
        raise queues_t.error("graphics", "a GPU needs at least one graphics queue")
    gpu = GpuProfile(
        name=t.get("name", str),
        memory_bytes=t.get("memory_bytes", int, minimum=1, maximum=L.MAX_BYTES, why=L.WHY_BYTES),
        queues=MappingProxyType(queues),
        link=_parse_link(t.table("link")),
        costs=_parse_costs(t.table("costs")),
        copy=_parse_copy(t.table("copy", None)),
        local_copy_gbps=_gbps(t, "local_copy_gbps", 300.0),
        cpu_threads=t.get("cpu_threads", int, None, minimum=1, maximum=L.MAX_THREADS, why=L.WHY_ALLOC),
        task_gap_ns=_ns(t, "task_gap_ns", 0),
        speed=t.get("speed", float, 1.0, above=0, maximum=L.MAX_SPEED),
        physical=t.get("physical", int, None, minimum=0, maximum=L.MAX_GPUS - 1, why=L.WHY_ALLOC),
        **_parse_overlap(t.table("queue_overlap", None)),
    )
    t.finish()
    return gpu


def _parse_overlap(t: Table) -> dict[str, Mapping]:
    """`[gpus.queue_overlap]`: an efficiency in (0, 2] per pair of OVERLAP_PAIRS, and per pass
    kind a table of the pairs it is in (`[gpus.queue_overlap.particle_render]`)."""
    for key in t.data:
        if key not in OVERLAP_PAIRS and key not in WORK_TERMS:
            raise t.error(key, f"unknown pair or pass kind{did_you_mean(key, [*OVERLAP_PAIRS, *WORK_TERMS])} "
                               f"(pairs: {', '.join(OVERLAP_PAIRS)}; or a pass kind's table of them)")
    by_kind = {}
    for kind in [k for k in t.data if k in WORK_TERMS]:
        by_kind[kind] = _overlap_pairs(t.table(kind))
    return {"queue_overlap": _overlap_pairs(t), "overlap_by_kind": MappingProxyType(by_kind)}


def _overlap_pairs(t: Table) -> Mapping[str, float]:
    given = {pair: t.get(pair, float, None, above=0, maximum=2.0, why="2 = each at full speed")
             for pair in OVERLAP_PAIRS}
    t.finish()
    return MappingProxyType({pair: v for pair, v in given.items() if v is not None})


def _parse_link(t: Table) -> LinkProfile:
    link = LinkProfile(
        pcie_gen=t.get("pcie_gen", int, choices=PCIE_LANE_GBPS.keys()),
        lanes=t.get("lanes", int, choices=PCIE_LANES),
        latency_ns=_ns(t, "latency_ns"),
        efficiency=t.get("efficiency", float, 1.0, above=0, maximum=1),
        h2d_gbps=_gbps(t, "h2d_gbps", None),
        d2h_gbps=_gbps(t, "d2h_gbps", None),
    )
    t.finish()
    return link


def _parse_costs(t: Table) -> Mapping[str, PassCost]:
    """One table per pass kind; a misspelt kind or work term is refused, not ignored."""
    costs: dict[str, PassCost] = {}
    for kind in list(t.data):
        if kind not in WORK_TERMS:
            raise t.error(kind, f"unknown pass kind{did_you_mean(kind, WORK_TERMS)} (kinds: "
                                f"{', '.join(WORK_TERMS)})")
        kt = t.table(kind)
        fixed = kt.get("fixed_ns", float, 0.0, minimum=0, maximum=L.MAX_TASK_NS, why=L.WHY_TIME)
        cores = kt.get("cores", float, None, minimum=0.01, maximum=L.MAX_THREADS, why=L.WHY_ALLOC)
        overhead = kt.get("cpu_overhead_ns", float, 0.0, minimum=0, maximum=L.MAX_TASK_NS,
                          why=L.WHY_TIME)
        from_pairs = kt.get("cores_from_pairs", bool, False)
        known = [f"ns_per_{term}" for term in work_terms(kind)]
        stderr = _parse_stderr(kt.table("stderr", {}), known) if kt.has("stderr") else {}
        term_cores = _parse_term_cores(kt, kind, cores) if kt.has("term_cores") else {}
        ns_per: dict[str, float] = {}
        for key in list(kt.rest()):
            if key in ("stderr", "term_cores"):
                continue
            if key not in known:
                extra = ['fixed_ns', 'cores', 'cpu_overhead_ns', 'cores_from_pairs', 'stderr',
                         'term_cores']
                raise kt.error(key, f"unknown cost key{did_you_mean(key, [*known, *extra])}"
                                    f" ({kind} takes {', '.join(extra)}, "
                                    f"{', '.join(known)})")
            ns_per[key.removeprefix("ns_per_")] = kt.get(key, float, minimum=0,
                                                         maximum=L.MAX_COEFFICIENT)
        kt.finish()
        costs[kind] = PassCost(fixed, MappingProxyType(ns_per), cores, overhead, from_pairs,
                               MappingProxyType(stderr), MappingProxyType(term_cores))
    return MappingProxyType(costs)


def _parse_term_cores(kt: Table, kind: str, cores: float | None) -> dict[str, float]:
    """A cost's cores per term (`[gpus.costs.<kind>.term_cores]`, keyed by work term): only
    beside the pass's own `cores`, which holds for the rest of its work."""
    t = kt.table("term_cores")
    if cores is None:
        raise kt.error("term_cores", "needs the pass's own `cores` beside it (the cores of its "
                                     "fixed part and of the terms not listed)")
    terms = work_terms(kind)
    out = {}
    for key in list(t.data):
        if key not in terms:
            raise t.error(key, f"unknown work term{did_you_mean(key, terms)} ({kind}'s: "
                               f"{', '.join(terms)})")
        out[key] = t.get(key, float, minimum=0.01, maximum=L.MAX_THREADS, why=L.WHY_ALLOC)
    t.finish()
    return out


def _parse_stderr(t: Table, known: list[str]) -> dict[str, float]:
    """A cost's standard errors, keyed like its coefficients (fixed_ns, ns_per_<term>)."""
    out = {}
    for key in list(t.data):
        if key != "fixed_ns" and key not in known:
            raise t.error(key, f"unknown coefficient{did_you_mean(key, ['fixed_ns', *known])}")
        out[key.removeprefix("ns_per_")] = t.get(key, float, minimum=0, maximum=L.MAX_COEFFICIENT)
    t.finish()
    return out


def with_cost_band(profile: "HardwareProfile", sigmas: float) -> "HardwareProfile":
    """`profile` with every pass cost moved by `sigmas` standard errors (see PassCost.shifted)."""
    gpus = tuple(replace(g, costs=MappingProxyType({k: c.shifted(sigmas) for k, c in g.costs.items()}))
                 for g in profile.gpus)
    return replace(profile, gpus=gpus)


def has_cost_stderr(profile: "HardwareProfile") -> bool:
    return any(c.stderr for g in profile.gpus for c in g.costs.values())


def _parse_copy(t: Table) -> Mapping[str, CopyCosts]:
    out: dict[str, CopyCosts] = {}
    for fam in list(t.data):
        if fam not in QUEUE_FAMILIES:
            raise t.error(fam, f"unknown queue family{did_you_mean(fam, QUEUE_FAMILIES)} "
                               f"(expected one of {list(QUEUE_FAMILIES)})")
        ft = t.table(fam)
        fixed = _ns(ft, "fixed_ns", 0)
        caps = {p: _gbps(ft, f"{p}_gbps") for p in COPY_PATHS if ft.has(f"{p}_gbps")}
        ft.finish()
        out[fam] = CopyCosts(fixed, MappingProxyType(caps))
    return MappingProxyType(out)


def _parse_peer(t: Table, n_gpus: int) -> PeerLink:
    ends = t.get("gpus", list)
    if len(ends) != 2 or not all(_is_index(g, n_gpus) for g in ends) or ends[0] == ends[1]:
        raise t.error("gpus", f"expected two different GPU indices in 0..{n_gpus - 1}, got {ends!r}")
    link = PeerLink(ends[0], ends[1], _gbps(t, "bandwidth_gbps"), _ns(t, "latency_ns"))
    t.finish()
    return link


def _is_index(value: object, n: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < n


def _peer_mesh(t: Table, n_gpus: int, explicit: tuple[PeerLink, ...]) -> tuple[PeerLink, ...]:
    """`[peer_mesh]` (a what-if): a direct link between every pair of GPUs (an NVLink
    switch), besides the pairs `[[peer_links]]` already lists, which keep their own."""
    bandwidth, latency = _gbps(t, "bandwidth_gbps"), _ns(t, "latency_ns")
    t.finish()
    linked = {frozenset((p.a, p.b)) for p in explicit}
    mesh = tuple(PeerLink(a, b, bandwidth, latency) for a in range(n_gpus) for b in range(a + 1, n_gpus)
                 if frozenset((a, b)) not in linked)
    return explicit + mesh


_MISSING = object()


def _ns(t: Table, key: str, default: object = _MISSING) -> int:
    """A fixed time in ns: an integer in [0, MAX_TASK_NS]."""
    args = () if default is _MISSING else (default,)
    return t.get(key, int, *args, minimum=0, maximum=L.MAX_TASK_NS, why=L.WHY_TIME)


def _gbps(t: Table, key: str, default: object = _MISSING) -> float:
    """A bandwidth in GB/s: a finite number in (0, MAX_GBPS]."""
    args = () if default is _MISSING else (default,)
    return t.get(key, float, *args, above=0, maximum=L.MAX_GBPS, why=L.WHY_GBPS)


def require_gpus(profile: HardwareProfile, n: int, file: str | None = None) -> None:
    if n > len(profile.gpus):
        raise InputError(f"asks for {n} GPUs but profile {profile.name!r} has {len(profile.gpus)} "
                         f"(--set profile.gpu_count={n} repeats its last GPU)", file=file,
                         field="schedule.gpus")
