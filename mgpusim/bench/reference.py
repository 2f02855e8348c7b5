"""The references the model's speed is measured against (:mod:`.model_speed`): raw SimPy's cost
of one resource use, and a plain SimPy model written by hand for one sort-first frame.

Why apart: they are not the model. The hand-written model shares nothing with the engine but
the cost model (its structure is written out, not read from a schedule), so a test can check
that both give the same presents and a benchmark can compare what each costs per frame.
"""
from __future__ import annotations

import time
from fractions import Fraction
from typing import Any, cast

import simpy
from simpy.core import SimTime

from mgpusim.model.costs import CostModel
from mgpusim.model.geometry import even_split
from mgpusim.model.tasks import CopyTask, HostCopyTask, PassTask
from mgpusim.schedules.program import build_program


def raw_simpy_uses_per_s(uses: int = 200_000, env: simpy.Environment | None = None) -> float:
    env = env if env is not None else simpy.Environment()
    res = simpy.Resource(env, capacity=1)

    def worker():
        for _ in range(uses):
            req = res.request()
            yield req
            yield env.timeout(1)
            res.release(req)

    env.process(worker())
    t0 = time.perf_counter()
    env.run()
    return uses / (time.perf_counter() - t0)


def _divide(nbytes: int, rate: Fraction) -> int:
    """ns to move `nbytes` at `rate` bytes/ns, rounded half up (as the model rounds)."""
    return (2 * nbytes * rate.denominator + rate.numerator) // (2 * rate.numerator)


def hand_written_sort_first(exp: Any, frames: int | None = None,
                            env: simpy.Environment | None = None) -> list[SimTime]:
    """The presents (ns) of a sort-first experiment with host copies, simulated by a plain
    SimPy model written for this one frame: a process per queue and for the host thread that
    dispatches copies, an event per task instance, a Resource for the memcpy threads. Task
    costs come from the same cost model; the structure (which task waits for which, on which
    queue) is written out here, not read from the schedule. Host memory is taken as never
    binding (each part at one thread's speed): true of the shipped sort-first experiments,
    and checked as it runs."""
    program = build_program(exp)
    frames = program.frames if frames is None else frames
    costs, host = CostModel(exp.profile), exp.profile.host
    task = {t.name: t for t in program.templates[0]}
    secondaries = range(1, exp.schedule.gpus)
    fif, buffers = exp.schedule.frames_in_flight, program.record["buffers"]
    cost = {t.name: costs.pass_ns(t.queue.device, t.kind, t.work) for t in task.values() if isinstance(t, PassTask)}
    for t in task.values():
        if isinstance(t, CopyTask):
            cost[t.name] = (costs.copy_setup_ns(t.queue.device, t.queue.family, t.path, t.peer)
                            + _divide(t.bytes, costs.link_bandwidth(t.queue.device, t.path)))
    part_rate = min(costs.memcpy_thread_cap(), costs.host_memory_bandwidth())
    host_copies = {i: cast(HostCopyTask, task[f"host_copy{i}"]) for i in secondaries}
    parts = {f"host_copy{i}": [host.host_copy_fixed_ns + _divide(size, part_rate) for size in
                               even_split(hc.bytes, hc.parts(host.memcpy_threads))]
             for i, hc in host_copies.items()}
    env = env if env is not None else simpy.Environment()
    done: dict[tuple[int, str], simpy.Event] = {}
    presents: list[SimTime] = []
    threads = simpy.Resource(env, capacity=host.memcpy_threads)
    copying = [0]  # parts on host memory now

    def ended(f: int, name: str) -> simpy.Event | None:
        """The event of task `name` of frame f (None before frame 0: nothing to wait for)."""
        if f < 0:
            return None
        ev = done.get((f, name))
        if ev is None:
            ev = done[(f, name)] = env.event()
        return ev

    def wait(*events):
        for ev in events:
            if ev is not None:
                yield ev

    def run(f: int, name: str, ns: int):
        yield env.timeout(ns)
        ev = ended(f, name)
        assert ev is not None  # f >= 0
        ev.succeed()

    def primary_graphics():
        for f in range(frames):
            yield from wait(ended(f - fif, "present"))
            yield from run(f, "render0", cost["render0"])
            yield from wait(ended(f, "render0"), *(ended(f, f"h2d{i}") for i in secondaries))
            yield from run(f, "composite", cost["composite"])
            yield from run(f, "present", cost["present"])
            presents.append(env.now)
            for i in secondaries:  # this frame's buffers were the last to need frame f - buffers
                for name in (f"d2h{i}", f"host_copy{i}", f"h2d{i}"):
                    done.pop((f - max(fif, buffers), name), None)
            for name in ("render0", "composite", "present") + tuple(f"render{i}" for i in secondaries):
                done.pop((f - max(fif, buffers), name), None)

    def secondary_graphics(i: int):
        for f in range(frames):
            yield from wait(ended(f - fif, "present"), ended(f - buffers, f"d2h{i}"))
            yield from run(f, f"render{i}", cost[f"render{i}"])

    def secondary_transfer(i: int):
        for f in range(frames):
            yield from wait(ended(f, f"render{i}"), ended(f - buffers, f"host_copy{i}"))
            yield from run(f, f"d2h{i}", cost[f"d2h{i}"])

    def primary_transfer():
        for f in range(frames):
            for i in secondaries:
                yield from wait(ended(f, f"host_copy{i}"), ended(f - buffers, "composite"))
                yield from run(f, f"h2d{i}", cost[f"h2d{i}"])

    def part(ns: int, left: list[int], f: int, name: str):
        with threads.request() as thread:
            yield thread
            copying[0] += 1
            if copying[0] * costs.memcpy_thread_cap() > costs.host_memory_bandwidth():
                raise AssertionError("host memory binds: this hand-written model does not share it")
            yield env.timeout(ns)
            copying[0] -= 1
        left[0] -= 1
        if not left[0]:
            ev = ended(f, name)
            assert ev is not None  # f >= 0
            ev.succeed()

    def host_dispatch():
        for f in range(frames):
            for i in secondaries:
                name = f"host_copy{i}"
                yield from wait(ended(f, f"d2h{i}"), ended(f - buffers, f"h2d{i}"))
                left = [len(parts[name])]
                for ns in parts[name]:
                    env.process(part(ns, left, f, name))

    env.process(primary_graphics())
    env.process(primary_transfer())
    env.process(host_dispatch())
    for i in secondaries:
        env.process(secondary_graphics(i))
        env.process(secondary_transfer(i))
    env.run()
    return presents


def reference_loop() -> float:
    """CPU seconds of a fixed pure-Python loop (dict and list work, as the model's): the figure
    every speed is divided by, so that a speed measured on a shared machine whose speed moves
    within minutes can be compared across runs (the benchmarks time the same loop)."""
    t0 = time.process_time()
    d: dict[int, int] = {}
    acc = []
    for i in range(300_000):
        d[i & 1023] = d.get(i & 1023, 0) + i
        acc.append(i ^ (i >> 3))
    return time.process_time() - t0 + 0 * len(acc)
