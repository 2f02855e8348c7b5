"""The analytic recurrence (:mod:`mgpusim.sim.analytic`) over many configurations at once.

Why: a sweep over hardware what-ifs runs one program structure thousands of times with other
task times. Here every configuration is one numpy *lane*: the task graph, queues, dependencies
and memcpy threads are those of one :class:`~mgpusim.sim.analytic.Analytic` model, and each
node's time (pass or copy time, host-copy part times, queue gap) and the host's dispatch,
submit and wake costs are arrays with one entry per lane. The recurrence is the scalar one
step for step (max-plus over frames, the memcpy-thread choice per lane), so a lane equals the
scalar model run with its times.

What a lane gives: the summary's timing fields (frame time and its spread, latency, window,
utilization of every queue and memcpy thread) and the fast-forward's finding (the first
repeat of the recurrence's state, found by the scalar model's rule; states are compared by a
64-bit hash (random odd multipliers, fixed seed), so two different states are taken as one with
a chance of about 2^-64 per pair of frames: that would only mislabel the fast_forward fields,
since every frame is computed). Every frame is computed (no extrapolation), so runs
longer than :data:`MAX_LANE_FRAMES` are left to the scalar model. Programs with skippable
tasks are refused: their skips are decisions per configuration, not arrays.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.tasks import PassTask
from mgpusim.schedules.base import FrameProgram
from mgpusim.sim.analytic import NEG, NO_START, Analytic
from mgpusim.sim.effects import choose_effects

#: Longest run (frames) computed as lanes: every frame is computed (no extrapolation), and each
#: lane keeps a state hash and every task's start and end per frame.
MAX_LANE_FRAMES = 1000
#: Most memcpy threads: a thread's choice packs (free time + 1) x threads + number in int64.
MAX_LANE_THREADS = 64
#: Lanes computed together (numpy arrays that fit in cache are faster than larger ones).
CHUNK_LANES = 4096
#: Most bytes of task starts and ends a chunk keeps for its utilization (fewer lanes a chunk
#: for long runs).
LOG_BYTES = 1 << 26
_IDLE = NEG + 2  # a memcpy thread idle since before the last dispatch (None in the scalar state)


@dataclass
class Lanes:
    """Per-lane inputs, one list per frame phase parallel to the model's nodes: a queue or CPU
    node's whole time, a host copy's part times (a list of arrays), each node's gap."""

    n: int
    time: list[list[Any]]
    gap: list[list[np.ndarray]]
    dispatch: np.ndarray
    submit: np.ndarray
    copy_wake: np.ndarray

    def take(self, idx: slice | np.ndarray) -> "Lanes":
        """The lanes `idx` only."""
        def cut(v: Any) -> Any:
            return [cut(x) for x in v] if isinstance(v, list) else v[idx]
        sub = cut(self.time)
        n = len(self.dispatch[idx])
        return Lanes(n, sub, cut(self.gap), self.dispatch[idx], self.submit[idx], self.copy_wake[idx])


def base_lanes(model: Analytic, n: int) -> Lanes:
    """`n` lanes that each are `model` as it is (its own times)."""
    def full(v: int) -> np.ndarray:
        return np.full(n, v, dtype=np.int64)
    time = [[[full(t) for _, t in node.part_times] if node.stream == "host" else full(node.time)
             for node in phase] for phase in model.phases]
    gap = [[full(node.gap) for node in phase] for phase in model.phases]
    return Lanes(n, time, gap, full(model.dispatch), full(model.submit), full(model.copy_wake))


def concat(parts: list[Lanes]) -> Lanes:
    """Lanes of models of one structure side by side (see :func:`structure`)."""
    def cat(vals: list[Any]) -> Any:
        if isinstance(vals[0], list):
            return [cat([v[i] for v in vals]) for i in range(len(vals[0]))]
        return np.concatenate(vals)
    return Lanes(sum(p.n for p in parts), cat([p.time for p in parts]), cat([p.gap for p in parts]),
                 cat([p.dispatch for p in parts]), cat([p.submit for p in parts]),
                 cat([p.copy_wake for p in parts]))


def structure(model: Analytic) -> tuple:
    """What lanes of two models must share to run together: every node's name, stream,
    dependencies and part count, the memcpy threads, frames, warm-up and the present task.
    (Times, gaps and host costs may differ per lane.)"""
    program = model.program
    nodes = tuple(tuple((n.name, n.stream, n.deps, len(n.part_times), n.cpu, n.device, n.engine)
                        for n in phase) for phase in model.phases)
    return (nodes, model.threads, model.lag, model.timeline, program.frames, program.warmup_frames,
            program.present_task)


def lanes_refusal(model: Analytic) -> str | None:
    """Why `model` cannot run as lanes (None: it can)."""
    if any(n.task.skip_if_busy for phase in model.phases for n in phase):
        return "skippable tasks (skips are decided per configuration)"
    if model.program.frames > MAX_LANE_FRAMES:
        return f"more than {MAX_LANE_FRAMES} frames"
    if model.threads > MAX_LANE_THREADS:
        return f"more than {MAX_LANE_THREADS} memcpy threads"
    return None


def run_lanes(model: Analytic, lanes: Lanes) -> dict[str, np.ndarray]:
    """Per-lane summary arrays (see :func:`_summary`), the repeat's fields and each
    resource's utilization included, :func:`_chunk` lanes at a time."""
    why = lanes_refusal(model)
    if why is not None:
        raise InputError(f"schedule {model.program.schedule!r} cannot run as lanes: {why}")
    return _by_chunks(model, lanes, _chunk(model), detect=True, log=True)


def frame_times(model: Analytic, lanes: Lanes) -> dict[str, np.ndarray]:
    """Frame time and latency (ms) per lane only: the first pass, no utilization."""
    return _by_chunks(model, lanes, CHUNK_LANES, detect=False, log=False,
                      keys=("frame_time_ms", "latency_ms"))


def _by_chunks(model: Analytic, lanes: Lanes, chunk: int, detect: bool, log: bool,
               keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The recurrence over `lanes`, `chunk` lanes at a time (numpy arrays that fit in cache
    are faster than larger ones), each chunk's summary arrays joined. `detect`: look for the
    repeat (the fast_forward fields); `log`: log every task's start and end, for each
    resource's utilization; `keys`: the summary's figures kept (None: all)."""
    out: dict[str, list[np.ndarray]] = {key: [] for key in keys or ()}
    for lo in range(0, lanes.n, chunk):
        run = _Pass(model, lanes.take(slice(lo, lo + chunk)), detect=detect, log=log)
        run.run()
        summary = _summary(model, run)
        if log:
            summary.update(_utilization(run, summary))
        for key in keys or summary:
            out.setdefault(key, []).append(summary[key])
    return {k: np.concatenate(v) for k, v in out.items()}


def _utilization(run: "_Pass", summary: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each resource's busy share of the summary's present window per lane (NaN where a lane
    never used it), rounded to 6 places as the scalar summary rounds it."""
    window = (summary["window_ns.0"], summary["window_ns.1"])
    span = np.maximum(window[1] - window[0], 1)
    return {f"utilization.{name}": np.where(used, np.round(busy / span, 6), np.nan)
            for name, (busy, used) in run.busy_by_resource(*window).items()}


def _chunk(model: Analytic) -> int:
    """Lanes per chunk: CHUNK_LANES, fewer where the run's logged task starts and ends (for
    utilization) would pass LOG_BYTES."""
    per_frame = sum(max(1, len(n.part_times)) for phase in model.phases for n in phase) / len(model.phases)
    fit = LOG_BYTES // max(1, int(16 * per_frame * model.program.frames))
    return int(min(CHUNK_LANES, max(1, fit)))


def _summary(model: Analytic, run: "_Pass") -> dict[str, np.ndarray]:
    """The summary's figures per lane, as :func:`mgpusim.results.summary.summarize_arrays`
    computes them from one run's arrays."""
    w, frames = model.program.warmup_frames, model.program.frames
    if w >= frames:
        raise InputError(f"no frame presents after the {w} warm-up frames (the run has {frames})",
                         field="schedule.warmup_frames")
    presents, latency = run.present[w:], (run.present - run.start)[w:]
    if len(presents) == 1:
        origin = run.present[w - 1] if w else run.start[w]
        presents = np.stack([origin, presents[0]])
    periods = np.diff(presents, axis=0)
    frame_time = periods.mean(axis=0)
    with np.errstate(divide="ignore"):
        fps = np.where(frame_time > 0, 1e9 / np.where(frame_time > 0, frame_time, 1), np.inf)
    out = {"frame_time_ms": frame_time / 1e6, "fps": fps, "latency_ms": latency.mean(axis=0) / 1e6,
           "frame_time_jitter_ms": periods.std(axis=0) / 1e6,
           "frame_time_min_ms": periods.min(axis=0) / 1e6, "frame_time_max_ms": periods.max(axis=0) / 1e6,
           "window_ns.0": presents[0].copy(), "window_ns.1": presents[-1].copy()}
    if run.found is not None:
        out.update(run.found)
    return out


@dataclass
class _Pass:
    """The recurrence over every frame for a chunk of lanes: frame starts and presents, each
    task's start and end (`log`: a resource's busy time in the steady window, known only once
    the run ends), and the repeat (`detect`)."""

    model: Analytic
    lanes: Lanes
    detect: bool = False
    log: bool = True
    found: dict[str, np.ndarray] | None = None

    def run(self) -> None:
        m, n = self.model, self.lanes.n
        frames = m.program.frames
        self.neg = np.full(n, NEG, dtype=np.int64)
        self.zero = np.zeros(n, dtype=np.int64)
        self.ends: list[dict[str, np.ndarray]] = []
        self.queue_end: dict[str, np.ndarray] = {}
        self.sub: dict[str, np.ndarray] = {}
        self.free = np.zeros((m.threads, n), dtype=np.int64)
        self.krow = np.arange(m.threads, dtype=np.int64)[:, None]
        #: resource -> (start, end) of each task on it; each memcpy-thread part (start, end, thread)
        self.qlog: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        self.plog: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.host_prev = self.neg
        self.start = np.empty((frames, n), dtype=np.int64)
        self.present = np.empty((frames, n), dtype=np.int64)
        if self.detect:
            self._detector = _Repeats(m, n)
        for f in range(frames):
            self._frame(f)
            if self.detect and f >= m.lag:
                self._detector.look(f, self._state_hash(f), self.present)
            if f > m.lag:
                self.ends[f - m.lag - 1] = {}
        if self.detect:
            self.found = self._detector.fields()

    def _frame(self, f: int) -> None:
        m, L = self.model, self.lanes
        phase = f % len(m.phases)
        here: dict[str, np.ndarray] = {}
        self.ends.append(here)
        first = np.full(self.lanes.n, NO_START, dtype=np.int64)
        for i, node in enumerate(m.phases[phase]):
            ready, cross = self.neg, self.neg
            for dep, off, crosses in node.deps:
                if off:
                    if f + off < 0:
                        continue
                    e = self.ends[f + off][dep]
                else:
                    e = here[dep]
                ready = np.maximum(ready, e)
                if crosses:
                    cross = np.maximum(cross, e)
            if node.stream == "host":
                here[node.name], first = self._host_copy(L.time[phase][i], ready, cross, first)
            else:
                here[node.name], first = self._queue_task(node, L.time[phase][i], L.gap[phase][i],
                                                          ready, cross, first)
        self.start[f], self.present[f] = first, here[m.program.present_task]

    def _host_copy(self, parts: list[np.ndarray], ready: np.ndarray, cross: np.ndarray,
                   first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.maximum(np.maximum(ready, self.host_prev), 0)
        if self.model.timeline:
            t = np.where(cross > NEG, np.maximum(t, cross + self.lanes.copy_wake + self.lanes.dispatch), t)
        self.host_prev = t
        end, krow, threads = self.neg, self.krow, self.model.threads
        if len(parts) <= threads and (self.free <= t).all() and all((took > 0).all() for took in parts):
            # every thread idle in every lane: part i on thread i, each starting at t
            for i, took in enumerate(parts):
                e = self.free[i] = t + took
                end = np.maximum(end, e)
                if self.log:
                    self.plog.append((t, e, np.full(len(t), i, dtype=np.int8)))
            return end, np.minimum(first, t)
        for took in parts:
            # the lowest-numbered idle thread, else the first to be idle (lowest number on ties):
            # the least key, an idle thread's number or a busy one's (free time + 1, number)
            key = np.where(self.free <= t, krow, (self.free + 1) * threads + krow).min(axis=0)
            s = np.where(key < threads, t, key // threads - 1)
            e = s + took
            tid = key % threads
            self.free = np.where(krow == tid, e, self.free)
            end = np.maximum(end, e)
            first = np.minimum(first, s)
            if self.log:
                self.plog.append((s, e, tid.astype(np.int8)))
        return end, first

    def _queue_task(self, node: Any, time: np.ndarray, gap: np.ndarray, ready: np.ndarray,
                    cross: np.ndarray, first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        L = self.lanes
        s = np.maximum(ready, self.queue_end.get(node.stream, self.zero))
        if self.model.timeline:
            woke = np.where(cross > NEG, cross + L.dispatch, NEG)
            if node.cpu:
                s = np.maximum(s, woke)
            else:
                clock = np.maximum(self.sub.get(node.stream, self.zero), woke) + L.submit
                self.sub[node.stream] = clock
                s = np.maximum(s, clock)
        s = s + gap
        e = self.queue_end[node.stream] = s + time
        if self.log:
            self.qlog.setdefault(f"{node.device}.{node.engine}", []).append((s, e))
        return e, np.minimum(first, s)

    def busy_by_resource(self, lo: np.ndarray, hi: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Resource -> (busy ns inside [lo, hi] per lane, whether the lane ever used it). Task
        by task on arrays of one chunk (stacking them all would cost more than the sums)."""
        def inside(start: np.ndarray, end: np.ndarray) -> np.ndarray:
            return np.minimum(np.maximum(end, lo), hi) - np.minimum(np.maximum(start, lo), hi)
        n, every = self.lanes.n, np.ones(self.lanes.n, dtype=bool)
        out = {}
        for name, log in self.qlog.items():
            busy = np.zeros(n, dtype=np.int64)
            for start, end in log:
                busy += inside(start, end)
            out[name] = (busy, every)
        if not self.plog:
            return out
        threads, lane = self.model.threads, np.arange(n)
        flat_busy, flat_used = np.zeros(threads * n, dtype=np.int64), np.zeros(threads * n, dtype=bool)
        for start, end, tid in self.plog:
            at = tid.astype(np.int64) * n + lane  # one thread per lane: no index twice
            flat_busy[at] += inside(start, end)
            flat_used[at] = True
        thread_busy, thread_used = flat_busy.reshape(threads, n), flat_used.reshape(threads, n)
        for k, tname in enumerate(self.model.thread_names):
            name = f"host.{tname}"
            if name in out:  # a CPU task's thread of the same name: one resource
                out[name] = (out[name][0] + thread_busy[k], every)
            else:
                out[name] = (thread_busy[k], thread_used[k])
        return out

    def _state_hash(self, f: int) -> np.ndarray:
        """A 64-bit hash per lane of the scalar model's state after frame f
        (:meth:`mgpusim.sim.analytic._Recurrence._state`): what the frames after it read,
        relative to frame f's present, each value times its position's odd multiplier, summed."""
        m, ref = self.model, self.present[f]
        values: list[Any] = [f % len(m.phases), len(self.queue_end), len(self.sub)]
        relative = [e for g in range(max(0, f - m.lag + 1), f + 1) for e in self.ends[g].values()]
        relative.extend(self.queue_end.values())
        if m.timeline:
            for q, c in self.sub.items():
                behind = np.maximum(c, self.queue_end.get(q, self.zero))
                relative.append(np.where(self.lanes.submit != 0, c, behind))
        idle = np.maximum(self.host_prev, 0)
        values.extend(np.where(t > idle, t - ref, _IDLE) for t in self.free)
        values.append(np.where(self.host_prev > NEG, self.host_prev - ref, NEG))
        mult = _multipliers(len(values) + len(relative))
        h = np.zeros(self.lanes.n, dtype=np.uint64)
        with np.errstate(over="ignore"):
            for v, k in zip(values, mult):
                h += np.asarray(v, dtype=np.int64).view(np.uint64) * k
            # the values relative to the present: sum(v * k) - present * sum(k)
            for v, k in zip(relative, mult[len(values):]):
                h += v.view(np.uint64) * k
            h -= ref.view(np.uint64) * mult[len(values):].sum(dtype=np.uint64)
        return h


def _multipliers(n: int) -> np.ndarray:
    """`n` odd 64-bit multipliers, the same in every run (a fixed seed)."""
    if len(_MULT) < n:
        rng = np.random.default_rng(0x5EED)
        _MULT[:] = (rng.integers(0, 2**63, size=max(n, 64), dtype=np.uint64) * np.uint64(2)
                    + np.uint64(1)).tolist()
    return np.array(_MULT[:n], dtype=np.uint64)


_MULT: list[int] = []


class _Repeats:
    """The scalar model's search for a repeat, per lane, over the state hashes of frames lag
    and later (kept as the run goes, searched once it ends): a frame's state seen before
    (since the last clear) is a repeat of period f - f1; with whole periods left to skip the
    search ends, otherwise it starts again after that frame (the scalar model clears what it
    saw). Each lane's hashes are sorted once: a repeat is a pair of equal neighbours."""

    def __init__(self, model: Analytic, n: int):
        self.frames, self.lag = model.program.frames, model.lag
        self.hashes = np.empty((n, max(self.frames - self.lag, 0)), dtype=np.uint64)

    def look(self, f: int, h: np.ndarray, present: np.ndarray) -> None:
        self.hashes[:, f - self.lag] = h
        self.present = present

    def fields(self) -> dict[str, np.ndarray]:
        n, width = self.hashes.shape
        period = np.full(n, -1, dtype=np.int64)
        from_frame = np.full(n, -1, dtype=np.int64)
        ns = np.zeros(n, dtype=np.int64)
        since = np.zeros(n, dtype=np.int64)  # frames before it (relative to lag) are forgotten
        todo = np.arange(n)
        while len(todo) and width > 1:
            h = self.hashes[todo]
            cols = np.arange(width)
            forgotten = cols[None, :] < since[todo, None]
            h = np.where(forgotten, np.uint64(2**64 - 1) - cols.astype(np.uint64), h)
            order = np.argsort(h, axis=1, kind="stable")
            sorted_h = np.take_along_axis(h, order, axis=1)
            pair = (sorted_h[:, 1:] == sorted_h[:, :-1]) & ~np.take_along_axis(forgotten, order[:, 1:], axis=1)
            second = np.where(pair, order[:, 1:], width)
            j = second.argmin(axis=1)
            hit = second[np.arange(len(todo)), j] < width
            lanes, j = todo[hit], j[hit]
            f = second[hit, j] + self.lag
            f1 = order[hit, j] + self.lag
            p = f - f1
            period[lanes], from_frame[lanes] = p, f1 + 1
            ns[lanes] = self.present[f, lanes] - self.present[f1, lanes]
            again = (self.frames - (f + 2)) // p <= 0
            since[lanes[again]] = f[again] + 1 - self.lag
            todo = lanes[again]
        return {"fast_forward.used": period > 0, "fast_forward.period_frames": period,
                "fast_forward.period_ns": ns, "fast_forward.from_frame": from_frame}


# ----- many hardware variants at once -------------------------------------------------------
def sweep(program: FrameProgram, costs: CostModel, pass_scale: np.ndarray, link_scale: np.ndarray,
          effects: frozenset[str] | None = None) -> dict[str, np.ndarray]:
    """Frame time and latency (ms, after warm-up) of one program on many hardware variants at
    once: variant i has every pass `pass_scale[i]` times as long and every link and host-memory
    transfer `link_scale[i]` times as long (rounded once, half up, like the model's costs).
    With both scales 1 it is :class:`Analytic` exactly; one numpy lane per variant
    (this module's lanes). Programs with skippable tasks are refused (their
    skips are decided per variant, not as arrays)."""
    if any(t.skip_if_busy for tasks in program.templates for t in tasks):
        raise InputError(f"schedule {program.schedule!r} has skippable tasks: sweep them one "
                         "configuration at a time (simulate(..., fidelity='analytic'))")
    pass_scale = np.asarray(pass_scale, dtype=np.float64)
    link_scale = np.asarray(link_scale, dtype=np.float64)
    model = Analytic(program, costs, effects if effects is not None else
                     choose_effects(program, costs.profile, "analytic"))
    lanes = base_lanes(model, len(pass_scale))

    def scaled(ns: float, scale: np.ndarray) -> np.ndarray:
        return np.floor(ns * scale + 0.5).astype(np.int64)
    for ph, phase in enumerate(model.phases):
        for i, node in enumerate(phase):
            if node.stream == "host":
                rate = node.rate
                assert rate is not None, "a host copy's node has its parts' rate"
                lanes.time[ph][i] = [node.fixed + scaled(size / float(rate), link_scale)
                                     for size in node.parts]
            elif isinstance(node.task, PassTask):
                raw = costs.pass_cost_ns(node.task.queue.device, node.task.kind, node.task.work)
                lanes.time[ph][i] = scaled(raw, pass_scale)
            elif node.rate is not None and node.nbytes:
                lanes.time[ph][i] = node.fixed + scaled(node.nbytes / float(node.rate), link_scale)
    return frame_times(model, lanes)
