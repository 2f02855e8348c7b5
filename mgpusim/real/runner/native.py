"""The native runner core: the planned nodes executed by C threads (`native_core.c`). It runs
on real GPUs unless MGPUSIM_RUNNER says otherwise (`choose`).

Why: the Python executor's threads hand each task on through the interpreter. With light 4-GPU
frames its sixteen threads keep the interpreter busy, and a thread the driver woke from a fence
wait then waited a median 0.08-0.15 ms for it (four H200s, docs/nvidia_h200_x4.md): such a
frame measured the runner. Here Python plans the run and the C threads only follow the plan:
- every GPU node gets a slot (command buffer, fence, query pool) recorded beforehand, from a ring
  of SLOTS_PER_KEY per recording key; a node reusing a slot waits until the slot's previous
  node was reaped (its timestamps read, its fence reset);
- every semaphore edge gets a semaphore from a ring of SEMAPHORES_PER_EDGE; a producer reusing
  one waits until the consumer of its previous use finished;
- every host copy's parts are byte ranges, copied with memcpy.
The threads are the Python executor's: a submit and a reap thread per VkQueue, one host-copy
dispatcher and K memcpy threads, each in (frame, position) order; the trace and submission rows
are the same.

What it does not run: skippable tasks, submit-time choices (the particle demo's newest-buffer
draw) and the as-built host loop's CPU tasks, which depend on the run's course in Python. A
program with any of them runs on the Python executor; `unsupported` says why.

Why not on lavapipe by default: there the runner's threads share the machine's cores with the
"GPUs'" rasterizer threads either way, the lavapipe profiles' host effects (a submit thread's
time per task, the threads' turns) were measured on the Python executor's runs, and a main job
on the core (2026-11-27) replayed no closer than the Python executor's jobs (held out 1.9 / 10.3 %
against 1.5-2.6 / 8-13 %, the machine's speed moving 84 % during the job).
"""
from __future__ import annotations

import ctypes
import os
from collections import defaultdict
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from mgpusim.model.errors import DependencyError, InputError, ScheduleError
from mgpusim.real.runner.plan import CPU_STREAM, HOST_STREAM, Node
from mgpusim.real.runner.work import CpuWork, GpuWork, HostWork
from mgpusim.real.vulkan import c_library, hotpath
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.vk_errors import VulkanError, result_name, vk
from mgpusim.schedules.base import FrameProgram

SOURCE = Path(__file__).with_name("native_core.c")
#: the environment variable that picks the runner core, and its values (auto: the native core on
#: real GPUs where it can run the program, the Python executor otherwise)
RUNNER_ENV = "MGPUSIM_RUNNER"
RUNNERS = ("auto", "python", "native")
#: recorded slots per recording key: how many of a key's submissions may be in flight at once
SLOTS_PER_KEY = 4
#: semaphores per semaphore edge of the template
SEMAPHORES_PER_EDGE = 4
#: the node table's columns, as native_core.c's enum
COLUMNS = ("kind", "queue", "device", "cmd", "fence", "pool", "stamps", "wait_off", "wait_n",
           "signal_off", "signal_n", "dep_off", "dep_n", "part_off", "part_n")
COL = {name: i for i, name in enumerate(COLUMNS)}
KIND_GPU, KIND_HOST = 0, 1
EDGE_DONE, EDGE_SUBMITTED, EDGE_REAPED = 0, 1, 2
STREAM_GPU, STREAM_HOST = 0, 1
N_OUT = 5  # seen, call, called, tick0, tick1
#: semaphores one task may wait on (native_core.c's MAX_WAITS)
MAX_WAITS = 64
ERR_VULKAN, ERR_STUCK, ERR_DEVICE, ERR_THREAD = 1, 2, 3, 4
#: the Vulkan calls the core makes, passed to it in this order (its CALL_* codes)
CALLS = ("vkQueueSubmit", "vkWaitForFences", "vkResetFences", "vkGetQueryPoolResults")


def wanted(asked: str | None = None) -> str:
    """The runner core asked for: `asked` (a run's `runner` argument), else MGPUSIM_RUNNER;
    auto (the default), python or native."""
    source = "runner" if asked is not None else RUNNER_ENV
    raw = asked if asked is not None else os.environ.get(RUNNER_ENV, "")
    raw = raw.strip().lower() or "auto"
    if raw not in RUNNERS:
        raise InputError(f"{source} must be one of {', '.join(RUNNERS)}, got {raw!r}", field=source)
    return raw


def unsupported(program: FrameProgram, nodes: list[Node]) -> str | None:
    """Why the native core cannot run `program`'s nodes, or None."""
    if any(t.skip_if_busy for tasks in program.templates for t in tasks):
        return "it has skippable tasks (decided at submit time)"
    for node in nodes:
        if isinstance(node.work, CpuWork):
            return f"task {node.task.name!r} is a CPU task of the as-built host loop"
        if isinstance(node.work, HostWork) and node.work.task.own_threads:
            return f"host copy {node.task.name!r} starts threads of its own"
        if isinstance(node.work, GpuWork) and node.work.choose is not None:
            return f"task {node.task.name!r} chooses its input at submit time"
        if sum(kind == "semaphore" for _p, kind in node.deps) > MAX_WAITS:
            return f"task {node.task.name!r} waits on more than {MAX_WAITS} semaphores"
    return None


def choose(program: FrameProgram, nodes: list[Node], lavapipe: bool,
           runner: str | None = None) -> tuple[str, str | None]:
    """The core that runs `nodes` ("native" or "python"; `runner` asks, else MGPUSIM_RUNNER)
    and, where the Python executor runs although the core was asked for or could have run,
    why (the run's summary records both)."""
    asked = wanted(runner)
    if asked == "python":
        return "python", None
    reason = unsupported(program, nodes)
    if reason is not None:
        return "python", f"the native core cannot run this program: {reason}"
    if asked == "native":
        library_path()  # a missing compiler is an error when the core was asked for
        return "native", None
    if lavapipe:
        return "python", ("lavapipe: its profiles' host effects are the Python executor's "
                          f"({RUNNER_ENV}=native runs the core)")
    try:
        library_path()
    except DependencyError as exc:
        return "python", str(exc)
    return "native", None


@lru_cache(maxsize=1)
def library_path() -> Path:
    """The built core, `<cache>/native/native_core-<hash>.so`, built with cc on first use (a
    machine without a compiler runs from a cache filled elsewhere: MGPUSIM_CACHE)."""
    return c_library.built(SOURCE)


@lru_cache(maxsize=1)
def _core() -> Any:
    lib = ctypes.CDLL(str(library_path()))  # a CDLL call releases the interpreter lock
    lib.mgpusim_run.restype = ctypes.c_int
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.mgpusim_run.argtypes = [p, p, p, p, p, i64, p, p, p, i64, p, p, p, p, i64, i64, i64, p, p, p]
    return lib


def _address(handle: Any) -> int:
    """A Vulkan handle (or a cffi pointer) as an integer."""
    return int(vk().ffi.cast("uintptr_t", handle)) if handle is not None else 0


def _ptr(array: np.ndarray) -> int:
    return array.ctypes.data


class NativeExecutor:
    """Runs `nodes` once on the native core; the same results as the Python `Executor`:
    `execute()` returns the trace rows, `submissions` the host side of each task."""

    def __init__(self, nodes: list[Node], host_threads: int, stall_timeout_s: float,
                 program: FrameProgram):
        reason = unsupported(program, nodes)
        if reason is not None:
            raise ScheduleError(f"the native runner core cannot run schedule {program.schedule!r}: "
                                f"{reason}")
        self.nodes, self.host_threads, self.stall_s = nodes, host_threads, stall_timeout_s
        self.submissions: list[tuple] = []
        self.skipped_frames: dict[str, list[int]] = {}
        self.read_frames: dict[str, dict[int, int | None]] = {}
        self._index = {id(n): i for i, n in enumerate(nodes)}

    # -- planning ---------------------------------------------------------------------------
    def _slots(self, taken: list[tuple[Gpu, Any, Any, list]]) -> tuple[dict[int, Any], dict[int, int]]:
        """Each GPU node's slot and the node that used the slot before it; every slot taken is
        listed in `taken` as soon as it is, so that a failure later gives it back."""
        by_key: dict[Any, list[Node]] = defaultdict(list)
        for node in self.nodes:
            if isinstance(node.work, GpuWork):
                by_key[(id(node.work), node.work.key(node.frame))].append(node)
        slot_of: dict[int, Any] = {}
        previous: dict[int, int] = {}
        for (_w, key), users in by_key.items():
            work = users[0].work
            assert isinstance(work, GpuWork)  # by_key holds GPU nodes only
            frame = users[0].frame
            count = min(SLOTS_PER_KEY, len(users))
            slots = work.gpu.take_recorded(work.queue, key, work.bound(frame), count)
            taken.append((work.gpu, work.queue, key, slots))
            for j, node in enumerate(users):
                slot_of[id(node)] = slots[j % count]
                if j >= count:
                    previous[id(node)] = self._index[id(users[j - count])]
        return slot_of, previous

    def _semaphores(self) -> tuple[dict[tuple[int, int], int], dict[int, list[int]]]:
        """The semaphore of each (producer, consumer) edge, and per producer the consumers of
        its semaphores' previous uses, which must have finished before it signals them again."""
        rings: dict[tuple[int, str], list[Any]] = {}
        uses: dict[tuple[int, str], list[Node]] = defaultdict(list)
        handle: dict[tuple[int, int], int] = {}
        reuse: dict[int, list[int]] = defaultdict(list)
        for prod in self.nodes:
            for cons in prod.sem_consumers:
                edge = (id(prod.work), cons.task.name)
                ring = rings.get(edge)
                if ring is None:
                    assert isinstance(prod.work, GpuWork)  # only queue work signals semaphores
                    ring = rings[edge] = [prod.work.gpu.semaphore() for _ in range(SEMAPHORES_PER_EDGE)]
                done = uses[edge]
                handle[(id(prod), id(cons))] = _address(ring[len(done) % len(ring)].handle)
                if len(done) >= len(ring):
                    reuse[id(prod)].append(self._index[id(done[-len(ring)])])
                done.append(cons)
        return handle, reuse

    def _tables(self, slot_of: dict[int, Any], previous: dict[int, int]) -> dict[str, Any]:
        """The arrays the core reads: nodes, semaphores, edges, parts, streams."""
        sem_of, reuse = self._semaphores()
        table = np.zeros((len(self.nodes), len(COLUMNS)), dtype=np.int64)
        flat: dict[str, list[int]] = {"sems": [], "deps": [], "parts": [], "part_node": []}
        keep: list[Any] = []  # the host copies' views, alive until the run ends
        for i, node in enumerate(self.nodes):
            self._edges(table[i], node, reuse, previous, flat["deps"])
            if isinstance(node.work, HostWork):
                self._host_row(table[i], i, node, flat, keep)
            else:
                self._gpu_row(table[i], node, slot_of[id(node)], sem_of, flat["sems"])
        streams: dict[str, list[int]] = defaultdict(list)
        for i, node in enumerate(self.nodes):
            streams[node.stream].append(i)
        order = [s for s in streams if not s.startswith(CPU_STREAM)]
        empty = {"sems": [0], "deps": [0, 0], "parts": [0, 0, 0], "part_node": [0]}
        arrays: dict[str, Any] = {name: np.array(values or empty[name], dtype=np.int64)
                                  for name, values in flat.items()}
        arrays.update(
            nodes=table, keep=keep, streams=len(order), part_count=len(flat["part_node"]),
            stream_nodes=np.array([i for s in order for i in streams[s]] or [0], dtype=np.int64),
            stream_off=np.cumsum([0] + [len(streams[s]) for s in order], dtype=np.int64),
            stream_kind=np.array([STREAM_HOST if s == HOST_STREAM else STREAM_GPU for s in order]
                                 or [0], dtype=np.int64))
        return arrays

    def _edges(self, row: np.ndarray, node: Node, reuse: dict[int, list[int]],
               previous: dict[int, int], deps: list[int]) -> None:
        """`node`'s waits as (producer, edge) pairs: its host and semaphore inputs, the
        consumers of the semaphores it reuses, the previous user of its slot."""
        row[COL["dep_off"]] = len(deps) // 2
        for prod, kind in node.deps:
            if kind == "host":
                deps += [self._index[id(prod)], EDGE_DONE]
            elif kind == "semaphore":
                deps += [self._index[id(prod)], EDGE_SUBMITTED]
        for p in reuse.get(id(node), []):
            deps += [p, EDGE_DONE]
        if id(node) in previous:
            deps += [previous[id(node)], EDGE_REAPED]
        row[COL["dep_n"]] = len(deps) // 2 - row[COL["dep_off"]]

    @staticmethod
    def _host_row(row: np.ndarray, i: int, node: Node, flat: dict[str, list[int]],
                  keep: list[Any]) -> None:
        """A host copy: its parts' (dst, src, bytes)."""
        assert isinstance(node.work, HostWork)
        row[COL["kind"]] = KIND_HOST
        row[COL["part_off"]] = len(flat["part_node"])
        for dst, src in node.work.parts(node.frame):
            keep += [dst, src]
            flat["parts"] += [dst.ctypes.data, src.ctypes.data, int(dst.nbytes)]
            flat["part_node"].append(i)
        row[COL["part_n"]] = len(flat["part_node"]) - row[COL["part_off"]]

    @staticmethod
    def _gpu_row(row: np.ndarray, node: Node, slot: Any, sem_of: dict[tuple[int, int], int],
                 sems: list[int]) -> None:
        """A GPU task: its queue, slot, and the semaphores it waits on and signals."""
        work = node.work
        assert isinstance(work, GpuWork)
        row[COL["kind"]] = KIND_GPU
        row[COL["queue"]] = _address(work.queue.handle)
        row[COL["device"]] = _address(work.gpu.device)
        row[COL["cmd"]] = _address(slot.cmd)
        row[COL["fence"]] = _address(slot.fence)
        row[COL["pool"]] = _address(slot.pool)
        row[COL["stamps"]] = slot.stamps.ctypes.data if slot.stamps is not None else 0
        row[COL["wait_off"]] = len(sems)
        sems += [sem_of[(id(prod), id(node))] for prod, kind in node.deps if kind == "semaphore"]
        row[COL["wait_n"]] = len(sems) - row[COL["wait_off"]]
        row[COL["signal_off"]] = len(sems)
        sems += [sem_of[(id(node), id(cons))] for cons in node.sem_consumers]
        row[COL["signal_n"]] = len(sems) - row[COL["signal_off"]]

    # -- running ----------------------------------------------------------------------------
    def execute(self) -> list[tuple]:
        """Run every node on the core; raise its first error."""
        taken: list[tuple[Gpu, Any, Any, list]] = []
        try:
            slot_of, previous = self._slots(taken)
            t = self._tables(slot_of, previous)
            out = np.zeros((len(self.nodes), N_OUT), dtype=np.int64)
            part_out = np.zeros((max(1, t["part_count"]), 3), dtype=np.int64)
            error = np.zeros(5, dtype=np.int64)
            v = vk()
            fn = [_address(v.ffi.addressof(v.lib, name)) for name in CALLS]
            _core().mgpusim_run(*fn, _ptr(t["nodes"]), len(self.nodes), _ptr(t["sems"]),
                                _ptr(t["deps"]), _ptr(t["parts"]), t["part_count"],
                                _ptr(t["part_node"]), _ptr(t["stream_nodes"]), _ptr(t["stream_off"]),
                                _ptr(t["stream_kind"]), t["streams"], self.host_threads,
                                int(self.stall_s * 1e9), _ptr(out), _ptr(part_out), _ptr(error))
        except BaseException:
            self._settle(taken)
            raise
        if error[0]:
            self._settle(taken)
            raise self._error(error)
        for gpu, queue, key, slots in taken:
            gpu.give_back(queue, key, slots)
        return self._rows(out, part_out, t)

    def _settle(self, taken: list[tuple[Gpu, Any, Any, list]]) -> None:
        """After a failed run: the devices idle, every taken slot's fence reset and given back."""
        try:
            for gpu in {id(g): g for g, _q, _k, _s in taken}.values():
                gpu.wait_idle()
            for gpu, _queue, _key, slots in taken:
                for slot in slots:
                    hotpath.reset_fence(gpu.device, slot)
        finally:
            for gpu, queue, key, slots in taken:
                gpu.give_back(queue, key, slots)

    def _error(self, error: np.ndarray) -> Exception:
        kind, node, other, result, call = (int(x) for x in error)
        label = self.nodes[node].label if 0 <= node < len(self.nodes) else "the core"
        other_label = self.nodes[other].label if 0 <= other < len(self.nodes) else ""
        if kind == ERR_VULKAN:
            return VulkanError(f"{CALLS[call]} ({label})", result_name(result))
        if kind == ERR_STUCK:
            return ScheduleError(f"{label} waited {self.stall_s:.0f} s for {other_label}: the "
                                 f"schedule is stuck (blocked dependency)")
        if kind == ERR_DEVICE:
            return ScheduleError(f"{other_label} did not finish on the device within "
                                 f"{self.stall_s:.0f} s")
        if 0 <= node < len(self.nodes):  # the only per-node refusal before the threads start
            return ScheduleError(f"{label} waits on {result} semaphores; the native runner core "
                                 f"takes at most {MAX_WAITS} (MGPUSIM_RUNNER=python runs it)")
        return ScheduleError(f"the native runner core could not start its threads (errno {result})")

    def _rows(self, out: np.ndarray, part_out: np.ndarray, t: dict[str, Any]) -> list[tuple]:
        """Trace rows and submission rows in the Python executor's shapes."""
        rows: list[tuple] = []
        part = 0
        for i, node in enumerate(self.nodes):
            seen, call, called, tick0, tick1 = (int(x) for x in out[i])
            task = node.task
            if isinstance(node.work, HostWork):
                self.submissions.append((node.frame, "host", "memcpy", task.name, seen, call, called))
                for _ in range(int(t["nodes"][i, COL["part_n"]])):
                    start, end, k = (int(x) for x in part_out[part])
                    size = int(t["parts"][3 * part + 2])
                    rows.append((node.frame, "host", f"thread{k}", task.step, task.name, start, end,
                                 size, node.waits_for))
                    part += 1
                continue
            work = node.work
            assert isinstance(work, GpuWork)
            clock = work.gpu.clock
            self.submissions.append((node.frame, f"gpu{work.device}", work.engine, task.name,
                                     seen, call, called))
            rows.append((node.frame, f"gpu{work.device}", work.engine, task.step, task.name,
                         clock.to_host_ns(tick0), clock.to_host_ns(tick1), work.nbytes,
                         node.waits_for))
        return rows
