"""How long a woken runner thread waits for the interpreter during a measured run.

    PYTHONPATH=. python tools/probes/h200_x4/interpreter_probe.py EXPERIMENT.toml \
        [--set KEY=VALUE ...] [--devices 0,1,2,3] [--period-us 100] --out DIR

A probe thread sleeps `--period-us` at a time, alone first (the idle baseline: the OS timer's own
slack) and then while the runner runs the experiment in the same process. Each wake-up's
lateness is how long the thread waited, after its sleep ended, for the CPU and for the
interpreter lock: what a submit thread waits after its fence signalled before it can call
vkQueueSubmit. With the machine's cores mostly idle (64 on the 4x H200 machine) the CPU is
there at once, so lateness beyond the baseline is the interpreter.

Why: on 4x H200 the threads waiting for another GPU's task saw its end 0.7-1.2 ms late in light
sort-first frames on 4 GPUs, one waiter as much as several, where AFR's single hand-off saw it
in 0.15 ms. This tells whether those threads waited for the interpreter (other runner threads
holding it) or inside the driver.

Also each runner thread's CPU time over its life (`time.thread_time_ns`, taken in the thread)
and the part of it inside Vulkan's C functions, where the interpreter lock is released: the
rest is the thread's Python, which holds the lock. Per thread (a queue's submit or reap thread,
the host-copy dispatcher, a memcpy thread, whose numpy copies run without the lock).

Writes DIR/run (the measured run, as `mgpusim run` writes it), DIR/probe.csv (phase: idle,
setup, frames or after; wake-up time on the run's trace clock; lateness in ns), DIR/threads.csv
(execution, thread, cpu_ns, wall_ns, driver_ns) and prints the lateness per phase, the
threads' CPU and Python time per frame and their load on the interpreter (`python_load`).
"""
from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd

IDLE_S = 1.0


class Probe(threading.Thread):
    """Sleeps `period_ns` at a time and records each wake-up's lateness until stopped."""

    def __init__(self, period_ns: int):
        super().__init__(name="interpreter-probe", daemon=True)
        self.period_ns = period_ns
        self.phase = "idle"
        self.rows: list[tuple[str, int, int]] = []
        self._done = threading.Event()

    def run(self) -> None:
        period_s = self.period_ns / 1e9
        while not self._done.is_set():
            before = time.monotonic_ns()
            time.sleep(period_s)
            woke = time.monotonic_ns()
            self.rows.append((self.phase, woke, woke - before - self.period_ns))

    def stop(self) -> None:
        self._done.set()
        self.join()

    def table(self) -> pd.DataFrame:
        return pd.DataFrame(self.rows, columns=["phase", "woke_ns", "late_ns"])


class DriverClock:
    """CPU time each thread spends inside Vulkan's C functions, where the interpreter lock is
    released: the `vulkan` binding's one call site (`_callApi`) wrapped around the C call only,
    after it has converted the arguments in Python, and the runner's per-task calls
    (`mgpusim.real.vulkan.hotpath`, straight on the C library) through a library whose functions
    are timed. A thread's CPU time less this is its Python time, which holds the lock (a memcpy
    thread's numpy copy aside)."""

    def __init__(self) -> None:
        self.spent: dict[int, int] = {}

    def timed(self, fn: Callable[..., object]) -> Callable[..., object]:
        """`fn` with its CPU time added to the calling thread's."""
        spent = self.spent

        def call(*args: object) -> object:
            start = time.thread_time_ns()
            try:
                return fn(*args)
            finally:
                ident = threading.get_ident()  # each thread adds to its own key only
                spent[ident] = spent.get(ident, 0) + time.thread_time_ns() - start
        return call

    def install(self) -> Callable[[], None]:
        """Wrap the binding's C calls and the hot path's; returns what undoes it."""
        import vulkan._vulkan as binding

        from mgpusim.real.vulkan import hotpath

        original, ffi, auto = binding._callApi, binding.ffi, binding._auto_handle

        def api(fn: Callable[..., object], *args: object) -> object:
            fn_args = [auto(i, j) for i, j in zip(args, ffi.typeof(fn).args)]
            return self.timed(fn)(*fn_args)

        binding._callApi = api
        hot_vk, timed_binding = hotpath.vk, _TimedBinding(hotpath.vk(), self)
        hotpath.vk = lambda: timed_binding  # type: ignore[assignment]

        def undo() -> None:
            binding._callApi = original
            hotpath.vk = hot_vk  # type: ignore[assignment]
        return undo


class _TimedBinding:
    """The `vulkan` module as the hot path sees it, with `lib`'s functions timed."""

    def __init__(self, module: Any, clock: DriverClock) -> None:
        self._module = module
        self.lib = _TimedLib(module.lib, clock)

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._module, name)
        setattr(self, name, value)  # looked up once
        return value


class _TimedLib:
    """A C library whose functions add their CPU time to the calling thread's."""

    def __init__(self, lib: Any, clock: DriverClock) -> None:
        self._lib, self._clock = lib, clock

    def __getattr__(self, name: str) -> Any:
        fn = self._clock.timed(getattr(self._lib, name))
        setattr(self, name, fn)  # wrapped once
        return fn


class ThreadClock:
    """Each runner thread's CPU and wall time over its life, taken inside the thread by
    wrapping the runner's thread body (`Executor._guard`) while a run is made, and the CPU time
    it spent in Vulkan's C functions (`driver`)."""

    def __init__(self, driver: DriverClock | None = None) -> None:
        self.rows: list[tuple[int, str, int, int, int]] = []
        self._lock = threading.Lock()
        self.driver = driver or DriverClock()

    def wrap(self, guard: Callable[..., None]) -> Callable[..., None]:
        clock = self

        def timed(executor: object, fn: Callable[..., None], *args: object) -> None:
            cpu, wall = time.thread_time_ns(), time.monotonic_ns()
            try:
                guard(executor, fn, *args)
            finally:
                row = (id(executor), threading.current_thread().name,
                       time.thread_time_ns() - cpu, time.monotonic_ns() - wall,
                       clock.driver.spent.pop(threading.get_ident(), 0))
                with clock._lock:
                    clock.rows.append(row)
        return timed

    def table(self) -> pd.DataFrame:
        """One row per thread: `execution` counts the runner's executions in the order they
        began (a pre-warm pass runs before the measured one), then thread, cpu_ns, wall_ns and
        driver_ns (its CPU time inside Vulkan's C functions)."""
        out = pd.DataFrame(self.rows, columns=["execution", "thread", "cpu_ns", "wall_ns", "driver_ns"])
        order = {e: k for k, e in enumerate(dict.fromkeys(out["execution"]))}
        return out.assign(execution=out["execution"].map(order))


class CpuProfile:
    """Where the runner threads' CPU time goes: a cProfile per thread timed by the thread's own
    CPU clock (so a thread's waits count for nothing), summed over the threads. The profiler's
    own cost per call inflates cheap functions; the ranking is what to read."""

    def __init__(self) -> None:
        if sys.version_info >= (3, 12):  # cProfile became one process-wide monitor
            raise SystemExit("--profile needs Python < 3.12: from 3.12 on only one cProfile can "
                             "be active in a process, and this one profiles each thread apart")
        self.profiles: list[cProfile.Profile] = []
        self._lock = threading.Lock()

    def wrap(self, guard: Callable[..., None]) -> Callable[..., None]:
        def profiled(executor: object, fn: Callable[..., None], *args: object) -> None:
            profile = cProfile.Profile(time.thread_time_ns, 1e-9)
            with self._lock:
                self.profiles.append(profile)
            profile.runcall(guard, executor, fn, *args)
        return profiled

    def top(self, count: int) -> str:
        """The `count` functions with the most own CPU time, as pstats prints them."""
        text = io.StringIO()
        stats = pstats.Stats(*self.profiles, stream=text) if self.profiles else None
        if stats is not None:
            stats.sort_stats("tottime").print_stats(count)
        return text.getvalue()


def count_recordings() -> tuple[list[int], Callable[[], None]]:
    """Count the command buffers the runner records (`Gpu._record`): a submission whose
    recorded command buffer is not back from the previous one records a new one, which is
    Python work the steady state otherwise does not have. Returns the count (a one-item list)
    and what undoes the counting."""
    from mgpusim.real.vulkan.device import Gpu

    count, original = [0], Gpu.__dict__["_record"]

    def counted(slot: Any, record: Callable[[Any], None], once: bool) -> None:
        count[0] += 1
        original.__func__(slot, record, once)

    Gpu._record = staticmethod(counted)  # type: ignore[method-assign]

    def undo() -> None:
        Gpu._record = original  # type: ignore[method-assign]
    return count, undo


def cpu_per_frame(threads: pd.DataFrame, frames: int) -> pd.DataFrame:
    """Per kind of runner thread (submit, reap, host-dispatch, memcpy, ...) of the last
    execution (the measured run's): threads, CPU time per frame (us) summed over them, the part
    of it outside Vulkan's C functions (`python_us_per_frame`, where a tracked driver time is
    given), and their CPU share of their own wall time."""
    threads = threads[threads["execution"] == threads["execution"].max()]
    kind = threads["thread"].str.replace(r"[-/]?(gpu)?\d.*$", "", regex=True)
    grouped = threads.assign(kind=kind).groupby("kind", sort=True)
    out = pd.DataFrame({"threads": grouped.size(),
                        "cpu_us_per_frame": grouped["cpu_ns"].sum() / frames / 1e3,
                        "python_us_per_frame": (grouped["cpu_ns"].sum()
                                                - grouped["driver_ns"].sum()) / frames / 1e3,
                        "cpu_share": grouped["cpu_ns"].sum() / grouped["wall_ns"].sum()})
    return out.round(3)


def python_load(threads: pd.DataFrame, trace: pd.DataFrame) -> dict[str, float]:
    """How much of the measured run the runner's threads (all but the memcpy threads, whose
    numpy copies run without the lock) spent in CPU and in Python, as shares of the run's span
    (first task's start to last task's end), and their Python time per GPU task. Why the span
    and not frames x frame time: it is the time the threads had."""
    threads = threads[threads["execution"] == threads["execution"].max()]
    runner = threads[~threads["thread"].str.startswith("memcpy")]
    span = int(trace["end_ns"].max() - trace["start_ns"].min())
    frames = int(trace["frame"].max()) + 1
    tasks = int((trace["device"] != "host").sum())
    python = int((runner["cpu_ns"] - runner["driver_ns"]).sum())
    return {"gpu_tasks_per_frame": round(tasks / frames, 2),
            "runner_cpu_share": round(int(runner["cpu_ns"].sum()) / span, 3),
            "runner_python_share": round(python / span, 3),
            "python_us_per_gpu_task": round(python / 1e3 / tasks, 1)}


def lateness(table: pd.DataFrame) -> pd.DataFrame:
    """Per phase: wake-ups, median / 90th / 99th percentile / largest lateness (us), and the share
    of wake-ups later than 0.5 ms."""
    def stats(late: pd.Series) -> pd.Series:
        us = late.to_numpy() / 1e3
        return pd.Series({"wakeups": len(us), "median_us": np.median(us),
                          "p90_us": np.percentile(us, 90), "p99_us": np.percentile(us, 99),
                          "max_us": us.max(), "over_0.5ms": float(np.mean(us > 500))})
    return table.groupby("phase", sort=False)["late_ns"].apply(stats).unstack().round(3)


def on_run_clock(table: pd.DataFrame, result: Any) -> pd.DataFrame:
    """Wake-up times on the run's trace clock (0 at its first task), and the run phase split
    into `setup` (devices, pipelines, warm-up submissions before the first task), `frames` (from
    the first task's start to the last task's end) and `after`."""
    origin = int(result.summary.get("clock_origin_ns", 0))
    end = int(result.trace["end_ns"].max())
    out = table.assign(woke_ns=table["woke_ns"] - origin)
    running = out["phase"] == "run"
    out.loc[running & (out["woke_ns"] < 0), "phase"] = "setup"
    out.loc[running & (out["woke_ns"] >= 0) & (out["woke_ns"] <= end), "phase"] = "frames"
    out.loc[running & (out["woke_ns"] > end), "phase"] = "after"
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("experiment", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--devices", default=None)
    ap.add_argument("--period-us", type=int, default=100)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="also profile the runner threads' CPU time and print the N functions "
                         "with the most of it (slows the run: its lateness is not the run's own)")
    args = ap.parse_args(argv)
    if args.period_us < 1:
        ap.error("--period-us must be >= 1")

    from mgpusim.io.writers import write_measured
    from mgpusim.model.toml_checks import int_list
    from mgpusim.real.runner.execute import run_experiment
    from mgpusim.real.runner.executor import Executor
    from mgpusim.schedules.experiment import load_experiment, parse_overrides

    exp = load_experiment(args.experiment, parse_overrides(args.overrides))
    devices = int_list(args.devices, "--devices")
    probe, clock, guard = Probe(args.period_us * 1000), ThreadClock(), Executor._guard
    probe.start()
    time.sleep(IDLE_S)
    probe.phase = "run"
    profile = CpuProfile() if args.profile else None
    timed = clock.wrap(guard)
    Executor._guard = profile.wrap(timed) if profile else timed  # type: ignore[method-assign]
    undo, recordings, stop_counting = clock.driver.install(), *count_recordings()
    try:  # the probe times the Python executor's threads
        result = run_experiment(exp, devices=devices, runner="python")
    finally:
        stop_counting()
        undo()
        Executor._guard = guard  # type: ignore[method-assign]
        probe.stop()
    args.out.mkdir(parents=True, exist_ok=True)
    write_measured(result, args.out / "run", "csv")
    table = on_run_clock(probe.table(), result)
    table.to_csv(args.out / "probe.csv", index=False)
    print(f"{exp.name}: frame time {result.summary['frame_time_ms']:.3f} ms, "
          f"switch interval {sys.getswitchinterval() * 1e6:.0f} us outside the run")
    print(lateness(table).to_string())
    threads = clock.table()
    threads.to_csv(args.out / "threads.csv", index=False)
    frames = int(result.trace["frame"].max()) + 1
    print(f"runner threads' CPU time per frame ({frames} frames):")
    print(cpu_per_frame(threads, frames).to_string())
    print(", ".join(f"{k} {v}" for k, v in python_load(threads, result.trace).items()))
    print(f"command buffers recorded: {recordings[0]} for {len(result.trace)} tasks run "
          f"(pre-warm frames and clock calibration included)")
    if profile is not None:
        print(profile.top(args.profile))
    return 0


if __name__ == "__main__":
    sys.exit(main())
