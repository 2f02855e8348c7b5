"""The effects the model can simulate, when a scene calls for each, and fidelity levels.

An effect is a mechanism of the event model that costs simulation time (a fluid solver, a
shared pool of cores, a submit-thread timeline). Each says *when a scene needs it*: a test over
the built program and the profile that is true whenever leaving the effect out could change
the trace. The model instantiates only the effects a scene needs, so a run that cannot show an
effect does not pay for it; `--effects +x,-y` forces one on or off (forcing an unneeded effect
on gives the same trace: tests check it).

Fidelity levels trade accuracy for time:

- ``full``: every needed effect.
- ``queues``: the event model with fixed-rate links (no link or host-memory sharing) and no
  shared executor (CPU-emulated GPUs run as if each had its own cores, the queues of one GPU
  as if each were a GPU of its own).
- ``analytic``: no event simulation at all (:mod:`mgpusim.sim.analytic`).
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.tasks import CopyTask, CpuTask, HostCopyTask, Task
from mgpusim.schedules.base import FrameProgram
from mgpusim.sim.effect_names import FIDELITIES
from mgpusim.sim.executors import shared_gpu_groups

Needed = Callable[[FrameProgram, HardwareProfile], bool]


@dataclass(frozen=True)
class Effect:
    name: str
    #: what the model does when the effect is on (and what it does instead when off)
    doc: str
    #: when a scene needs it, in words (the `needed` test, for the docs and `--help`)
    when: str
    needed: Needed
    #: False: the effect cannot be forced on where the scene lacks its mechanism
    forceable: bool = True


def _all_tasks(program: FrameProgram) -> Iterable[Task]:
    for tasks in program.templates:
        yield from tasks


def _link_channels_shared(program: FrameProgram, profile: HardwareProfile) -> bool:
    """A link direction used by copies of more than one queue (a copy holds its queue while it
    crosses the link, so copies of one queue never overlap)."""
    users: dict[tuple, set] = {}
    for t in _all_tasks(program):
        if isinstance(t, CopyTask):
            key = (t.queue.device, t.path, t.peer if t.path in ("p2p", "group") else None)
            users.setdefault(key, set()).add(t.queue)
    return any(len(q) > 1 for q in users.values())


def _host_pcie_shared(program: FrameProgram, profile: HardwareProfile) -> bool:
    """A PCIe direction with a host capacity (host.pcie_d2h_gbps / pcie_h2d_gbps) is crossed by
    copies of two or more GPUs."""
    users: dict[str, set[int]] = {}
    for t in _all_tasks(program):
        if isinstance(t, CopyTask) and profile.host.pcie_gbps(t.path):
            users.setdefault(t.path, set()).add(t.queue.device)
    return any(len(gpus) > 1 for gpus in users.values())


def _host_copies(program: FrameProgram) -> bool:
    return any(isinstance(t, HostCopyTask) for t in _all_tasks(program))


def _own_thread_copies(program: FrameProgram) -> int:
    """The most host copies of one frame phase that start threads of their own."""
    return max((sum(isinstance(t, HostCopyTask) and t.own_threads for t in tasks)
                for tasks in program.templates), default=0)


def _copy_caps_bind(program: FrameProgram, profile: HardwareProfile) -> bool:
    """A copy whose queue family has a rate cap below its path's bandwidth."""
    costs = CostModel(profile)
    for t in _all_tasks(program):
        if not isinstance(t, CopyTask) or (t.path == "p2p" and t.peer is None):
            continue
        cap = costs.copy_cap(t.queue.device, t.queue.family, t.path)
        if cap is None:
            continue
        if t.path == "group":
            bw = costs.group_bandwidth(*t.ends())
        else:
            bw = (costs.peer_bandwidth(t.queue.device, t.peer) if t.path == "p2p"  # type: ignore[arg-type]
                  else costs.link_bandwidth(t.queue.device, t.path))
        if cap < bw:
            return True
    return False


def _frame_work(program: FrameProgram, profile: HardwareProfile) -> bool:
    """A CPU task starts threads or records command buffers, or a host copy starts threads of
    its own, that cost host time."""
    host = profile.host
    return any(isinstance(t, CpuTask) and (t.threads and host.thread_start_ns
                                            or t.command_buffers and host.record_ns)
               or isinstance(t, HostCopyTask) and t.own_threads and host.thread_start_ns
               for t in _all_tasks(program))


def _uncached(program: FrameProgram, profile: HardwareProfile) -> bool:
    """A host copy reads uncached memory, more slowly than a memcpy thread copies."""
    if not any(isinstance(t, HostCopyTask) and t.uncached for t in _all_tasks(program)):
        return False  # (the rates are not read: an override of them would change nothing)
    slow = profile.host.uncached_read_gbps
    return bool(slow) and slow < profile.host.memcpy_thread_gbps


def _gaps(program: FrameProgram, profile: HardwareProfile) -> bool:
    return any(not isinstance(t, (HostCopyTask, CpuTask)) and profile.gpus[t.queue.device].task_gap_ns
               for t in _all_tasks(program))


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("link_sharing",
           "concurrent copies share a link direction max-min fairly (fluid solver); off: each copy "
           "crosses at its own fixed rate",
           "a link direction is used by copies of more than one queue",
           _link_channels_shared),
    Effect("host_pcie",
           "every device-to-host (host-to-device) copy crosses its GPU's link and the host side "
           "of PCIe (host.pcie_d2h_gbps / host.pcie_h2d_gbps), shared by all the GPUs' copies of "
           "that direction max-min fairly across both (progressive filling); off: each GPU's link "
           "is its own",
           "host.pcie_d2h_gbps or host.pcie_h2d_gbps is set and copies of two or more GPUs cross "
           "that direction",
           _host_pcie_shared),
    Effect("copy_engine_caps",
           "a queue family's own copy rate limits its copies; off: only the link limits them",
           "a copy queue's rate cap is below the bandwidth of a path it copies over",
           _copy_caps_bind),
    Effect("host_memory_sharing",
           "host-copy parts share host memory bandwidth (fluid solver); off: each part at one "
           "memcpy thread's speed",
           "the schedule has host copies and the host has more than one memcpy thread, or "
           "several host copies start threads of their own",
           lambda p, prof: _host_copies(p) and (prof.host.memcpy_threads > 1 or _own_thread_copies(p) > 1)),
    Effect("shared_executor",
           "the GPUs' passes and copies, host copies and submit threads are work on one pool of "
           "host cores (CPU-emulated GPUs); off: every device runs its own work",
           "the profile's GPUs share the host CPU (host.gpus_share_cpu)",
           lambda p, prof: prof.host.gpus_share_cpu, forceable=False),
    Effect("shared_gpu",
           "the passes and copies on the queues of one physical GPU (of one or several logical "
           "GPUs) share its execution throughput, by each pair's overlap efficiency "
           "(gpus.queue_overlap); off: every queue is a server of its own",
           "a physical GPU runs work on two queues whose pair overlaps less than perfectly "
           "(queue_overlap < 2, or two logical GPUs on it: gpus.physical), on GPUs that do not "
           "share the host CPU",
           lambda p, prof: bool(shared_gpu_groups(p, prof))),
    Effect("host_submission",
           "per-queue submit threads (host.submit_ns) and host wake-up before work fed by another "
           "device (host.dispatch_ns; a host copy's thread also host.host_copy_wake_ns); off: work "
           "starts when its inputs are ready",
           "host.submit_ns, host.dispatch_ns or host.host_copy_wake_ns is non-zero",
           lambda p, prof: bool(prof.host.submit_ns or prof.host.dispatch_ns
                                or prof.host.host_copy_wake_ns)),
    Effect("busy_wake",
           "a copy about to start within host.busy_wake_window_ns of another GPU's core-filling "
           "pass starting: per (pass, GPU) pair, host.busy_wake_share of them first wait "
           "host.busy_wake_ns (at most the pass's remaining work), a core idle meanwhile (the "
           "copy's thread queued behind the pass's threads on one core); off: none",
           "the GPUs share the host CPU, the schedule has 2 or more GPUs, and host.busy_wake_share "
           "and host.busy_wake_ns are non-zero",
           lambda p, prof: bool(prof.host.gpus_share_cpu and prof.host.busy_wake_share
                                and prof.host.busy_wake_ns and p.gpus > 1)),
    Effect("host_frame_work",
           "the application's per-frame host work: a CPU task that starts (and joins) threads "
           "costs host.thread_start_ns each, one that records and submits command buffers "
           "host.record_ns each, and a host copy on threads of its own starts its parts one "
           "after another, host.thread_start_ns apart; off: they cost only their own time",
           "a CPU task starts threads or records command buffers, or a host copy starts threads "
           "of its own, and host.thread_start_ns or host.record_ns is non-zero",
           _frame_work),
    Effect("uncached_reads",
           "a host copy whose source is uncached (write-combined) host memory reads it at "
           "host.uncached_read_gbps per memcpy thread; off: at host.memcpy_thread_gbps",
           "a host copy reads uncached memory and host.uncached_read_gbps is set below "
           "host.memcpy_thread_gbps",
           _uncached),
    Effect("task_gaps",
           "a GPU's idle time between two tasks on a queue (task_gap_ns); off: none",
           "a GPU the schedule uses has task_gap_ns > 0",
           _gaps),
    Effect("memory_capacity",
           "each GPU's resident data is checked against its memory before the run, and reported",
           "always (it is a check before the run, not simulated time)",
           lambda p, prof: True),
)}

#: The effects whose `needed` test reads a link's rate (every other test reads the program,
#: the GPUs, the host and which peer links there are): between two profiles that differ only
#: in their links' rates and latencies, only these can change (:func:`needed_on_links`).
READS_LINK_RATES = frozenset({"copy_engine_caps"})


def needed_on_links(program: FrameProgram, profile: HardwareProfile, needed: frozenset[str]) -> frozenset[str]:
    """`choose_effects(program, profile)`, given `needed`, what it is on a profile that differs
    from `profile` only in its links' rates and latencies (the caller checks that): only the
    tests of :data:`READS_LINK_RATES` are run again. Why: a search over links would run every
    test once per link, on the same program."""
    again = {name for name in READS_LINK_RATES if EFFECTS[name].needed(program, profile)}
    return frozenset((needed - READS_LINK_RATES) | again)


#: Effects the `queues` level leaves out.
QUEUES_OMITS = frozenset({"link_sharing", "host_pcie", "host_memory_sharing", "shared_executor", "shared_gpu",
                          "busy_wake"})
#: Effects the `analytic` level has no mechanism for (:mod:`mgpusim.sim.analytic` takes them as
#: unshared and lists them as approximations): they cannot be forced on there.
ANALYTIC_OMITS = QUEUES_OMITS


def approximations(program: FrameProgram, profile: HardwareProfile, chosen: frozenset[str],
                   needed: frozenset[str] | None = None) -> list[str]:
    """What a run with effects `chosen` leaves out that this scene needs (``full`` with no
    effect forced off would model it), each as ``name: what the model does instead``: the
    summary's `approximations`. Why: a level that approximates says so beside its figures,
    rather than reading like the full model's. `needed`: `choose_effects(program, profile)`
    where the caller has it already."""
    left = sorted((choose_effects(program, profile) if needed is None else needed) - chosen)
    return [f"{name}: {EFFECTS[name].doc.partition('off: ')[2] or 'left out'}" for name in left]


def parse_effects(text: str | None, option: str = "--effects") -> dict[str, bool]:
    """`+x,-y` -> {"x": True, "y": False}; unknown names are an input error."""
    out: dict[str, bool] = {}
    for item in (text or "").split(","):
        item = item.strip()
        if not item:
            continue
        sign, name = item[0], item[1:]
        if sign not in "+-" or name not in EFFECTS:
            close = difflib.get_close_matches(item.lstrip("+-"), EFFECTS, n=1)
            hint = f" (did you mean {sign if sign in '+-' else '+'}{close[0]}?)" if close else ""
            raise InputError(f"{item!r} is not +name or -name with a name among "
                             f"{', '.join(EFFECTS)}{hint}", field=option)
        out[name] = sign == "+"
    return out


def choose_effects(program: FrameProgram, profile: HardwareProfile, fidelity: str = "full",
                   force: Mapping[str, bool] | None = None, needed: frozenset[str] | None = None) -> frozenset[str]:
    """The effects to instantiate: those the scene needs, less what the fidelity level leaves
    out, with `force` applied last. `needed`: `choose_effects(program, profile)` where the
    caller has it already (the tests read the whole program)."""
    if fidelity not in FIDELITIES:
        raise InputError(f"fidelity must be one of {', '.join(FIDELITIES)}, got {fidelity!r}",
                         field="fidelity")
    chosen = ({name for name, e in EFFECTS.items() if e.needed(program, profile)} if needed is None
              else set(needed))
    if fidelity != "full":
        chosen -= QUEUES_OMITS
    for name, on in (force or {}).items():
        if name not in EFFECTS:
            raise InputError(f"unknown effect {name!r} (known: {', '.join(EFFECTS)})", field="effects")
        if on and fidelity == "analytic" and name in ANALYTIC_OMITS:
            raise InputError(f"effect {name!r} cannot be forced on at --fidelity analytic, which has "
                             f"no mechanism for it (nor for {', '.join(sorted(ANALYTIC_OMITS - {name}))}): "
                             "use --fidelity queues or full", field="effects")
        if on and not EFFECTS[name].forceable and not EFFECTS[name].needed(program, profile):
            raise InputError(f"effect {name!r} cannot be forced on: {EFFECTS[name].when} is not "
                             "the case here", field="effects")
        (chosen.add if on else chosen.discard)(name)
    return frozenset(chosen)
