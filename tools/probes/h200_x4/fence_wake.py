"""Where a runner thread woken by a task's end spends its wait: the driver, then the interpreter.

    PYTHONPATH=. python tools/probes/h200_x4/fence_wake.py EXPERIMENT [--set KEY=VALUE ...] \
        [--devices 0,1,2,3] --out DIR
    PYTHONPATH=. python tools/probes/h200_x4/fence_wake.py --report FOLDER

Why: in light sort-first frames on four GPUs the runner's threads see another GPU's task end
0.3-1.2 ms late, where XR's see it within 0.2 ms, and the replay misses that frame by 15-17 %
(docs/nvidia_h200_x4.md). Earlier probes said the interpreter was busy; this one splits each
wake where it happens. The thread in vkWaitForFences calls it through a small C function
(`fence_wake.c`) that reads the clock as the driver returns, before the thread runs Python
again. So `driver` = the task's end (its GPU timestamp) to the driver's return, and
`interpreter` = the driver's return to the thread's next Python line. The other threads waiting
for the same task (in Python, on the watcher's condition) record when they ran on (`woken`).

Writes DIR/run (the measured run, as `mgpusim run` writes it), DIR/waits.csv (per fence wait
that returned signalled: thread, frame, task, call, c_return, resume) and DIR/woken.csv (per
thread that waited for a task: thread, frame, task, enter, exit), on the trace's clock, and
prints the split. `--report FOLDER` prints it again for every such DIR below FOLDER, or from
the packed `waits.parquet` / `woken.parquet` of a committed folder.

The C function is built with the system's C compiler into $MGPUSIM_CACHE/native (else
~/.cache/mgpusim/native) the first time, as the runner's native core is; on a machine without
one, bring the built `fence_wake-<hash>.so` in that cache (the NVIDIA machines have no
compiler: carry `.spvcache` built here).
"""
from __future__ import annotations

import argparse
import ctypes
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from mgpusim.model.errors import DependencyError
from mgpusim.real.vulkan import c_library

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "fence_wake.c"
#: the run's first frames, left out of the split (the study's warm-up)
WARMUP = 20


def shim(cache: Path | None = None) -> Path:
    """The built C function's library (`c_library.built`: into `cache`, default
    `$MGPUSIM_CACHE/native`), built from `fence_wake.c` if it is not there yet."""
    try:
        return c_library.built(SOURCE, cache)
    except DependencyError as exc:
        raise SystemExit(str(exc)) from None


class Recorder:
    """Puts the stamped fence wait in place of the runner's, and records each wait."""

    def __init__(self, lib_path: Path):
        self.lib = ctypes.CDLL(str(lib_path))
        self.lib.wait_stamped.restype = ctypes.c_int32
        self.lib.wait_stamped.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32,
                                          ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint64,
                                          ctypes.POINTER(ctypes.c_int64)]
        self.waits: list[tuple] = []
        self.woken: list[tuple] = []
        self._label = threading.local()
        self._undo: list[Callable[[], None]] = []

    def install(self) -> None:
        from mgpusim.real.vulkan import device, hotpath
        from mgpusim.real.vulkan.vk_errors import vk
        v = vk()
        fn = int(v.ffi.cast("uintptr_t", v.ffi.addressof(v.lib, "vkWaitForFences")))
        wait_fence, finished = hotpath.wait_fence, device.Submission.finished
        lib, label, waits, woken = self.lib, self._label, self.waits, self.woken

        def stamped(dev: Any, slot: Any, timeout_ns: int) -> bool:
            returned = ctypes.c_int64()
            call = time.monotonic_ns()
            result = lib.wait_stamped(fn, int(v.ffi.cast("uintptr_t", dev)), 1,
                                      int(v.ffi.cast("uintptr_t", slot.fences)), 1,
                                      max(0, timeout_ns), ctypes.byref(returned))
            resume = time.monotonic_ns()
            if result < 0:
                raise RuntimeError(f"vkWaitForFences returned {result}")
            if result == 0:
                waits.append((threading.current_thread().name, getattr(label, "text", ""),
                              call, returned.value, resume))
            return result == 0

        def labelled(sub: Any, timeout_ns: int) -> bool:
            label.text = sub.label
            enter = time.monotonic_ns()
            done = finished(sub, timeout_ns)
            if done:
                woken.append((threading.current_thread().name, sub.label, enter, time.monotonic_ns()))
            return done

        hotpath.wait_fence, device.Submission.finished = stamped, labelled
        self._undo = [lambda: setattr(hotpath, "wait_fence", wait_fence),
                      lambda: setattr(device.Submission, "finished", finished)]

    def uninstall(self) -> None:
        for undo in self._undo:
            undo()
        self._undo = []

    def tables(self, origin: int) -> tuple[pd.DataFrame, pd.DataFrame]:
        """(waits, woken) on the trace's clock (`origin`: the run's clock origin), without the
        waits of the untimed frames run before it (their labels name the same frames)."""
        waits = _labelled(pd.DataFrame(self.waits, columns=["thread", "label", "call", "c_return", "resume"]))
        woken = _labelled(pd.DataFrame(self.woken, columns=["thread", "label", "enter", "exit"]))
        for table, cols in ((waits, ["call", "c_return", "resume"]), (woken, ["enter", "exit"])):
            table[cols] = table[cols] - origin
        return waits[waits["call"] >= 0], woken[woken["enter"] >= 0]


def _labelled(table: pd.DataFrame) -> pd.DataFrame:
    """A submission's label ("frame F task") as frame and task columns; unlabelled rows dropped."""
    table = table[table["label"].str.startswith("frame ")].copy()
    parts = table.pop("label").str.split(" ", n=2, expand=True)
    table.insert(1, "frame", parts[1].astype(int) if len(table) else pd.Series(dtype=int))
    table.insert(2, "task", parts[2] if len(table) else pd.Series(dtype=str))
    return table


def _kinds(table: pd.DataFrame) -> pd.DataFrame:
    """Thread kind (its name without GPU and queue) and task kind (its name without a GPU digit)."""
    return table.assign(thread=table["thread"].str.replace(r"-?gpu\d.*$|\d+$", "", regex=True),
                        task=table["task"].str.replace(r"\d+(\.|$)", r"\1", regex=True))


def split(trace: pd.DataFrame, waits: pd.DataFrame, woken: pd.DataFrame,
          warmup: int = WARMUP) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per (thread kind, task kind), in us: for the thread inside the driver's fence wait, the
    median and 90th percentile of `driver` (task end -> the driver returned) and `interpreter`
    (-> the thread ran Python again); for every thread that waited, `ran_on` (task end -> it ran
    on). Frames before `warmup` are left out, and from `ran_on` the threads that began waiting
    only after the task had ended (they did not wait for it)."""
    end = trace[trace["frame"] >= warmup].groupby(["frame", "task"])["end_ns"].max().rename("end")
    w = waits.join(end, on=["frame", "task"], how="inner")
    w = _kinds(w.assign(driver=(w["c_return"] - w["end"]) / 1e3,
                        interpreter=(w["resume"] - w["c_return"]) / 1e3))
    k = woken.join(end, on=["frame", "task"], how="inner")
    k = _kinds(k[k["enter"] < k["end"]].assign(ran_on=lambda d: (d["exit"] - d["end"]) / 1e3))
    q = lambda s: s.quantile(0.9)  # noqa: E731
    watcher = w.groupby(["thread", "task"]).agg(n=("driver", "size"), driver_median=("driver", "median"),
                                               driver_p90=("driver", q),
                                               interpreter_median=("interpreter", "median"),
                                               interpreter_p90=("interpreter", q))
    every = k.groupby(["thread", "task"]).agg(n=("ran_on", "size"), ran_on_median=("ran_on", "median"),
                                             ran_on_p90=("ran_on", q))
    return watcher.round(0), every.round(0)


def measure(experiment: Path, overrides: list[str], devices: list[int] | None, out: Path) -> str:
    """Run `experiment` with the stamped waits in place; write DIR/run, waits.csv, woken.csv."""
    from mgpusim.io.writers import write_measured
    from mgpusim.real.runner.execute import run_experiment
    from mgpusim.schedules.experiment import load_experiment, parse_overrides
    exp = load_experiment(experiment, parse_overrides(overrides))
    recorder = Recorder(shim())
    recorder.install()
    try:  # the probe stamps the Python executor's waits
        result = run_experiment(exp, devices=devices, runner="python")
    finally:
        recorder.uninstall()
    out.mkdir(parents=True, exist_ok=True)
    write_measured(result, out / "run", "csv")
    waits, woken = recorder.tables(int(result.summary["clock_origin_ns"]))
    waits.to_csv(out / "waits.csv", index=False)
    woken.to_csv(out / "woken.csv", index=False)
    return f"{exp.name}: frame time {result.summary['frame_time_ms']:.3f} ms"


def report(folder: Path, warmup: int = WARMUP) -> str:
    """The split of every measured DIR below `folder`, or of its packed tables."""
    texts = []
    if (folder / "waits.parquet").is_file():
        waits, woken = pd.read_parquet(folder / "waits.parquet"), pd.read_parquet(folder / "woken.parquet")
        ends = pd.read_parquet(folder / "ends.parquet")
        runs = [(run, ends[ends["run"] == run], waits[waits["run"] == run], woken[woken["run"] == run])
                for run in sorted(ends["run"].unique())]
    else:
        runs = [(d.name, pd.read_csv(d / "run" / "trace.csv"), pd.read_csv(d / "waits.csv"),
                 pd.read_csv(d / "woken.csv")) for d in sorted(p.parent for p in folder.rglob("waits.csv"))]
    for name, trace, waits, woken in runs:
        watcher, every = split(trace, waits, woken, warmup)
        texts.append(f"== {name}\nthe thread in the driver's fence wait (us):\n{watcher.to_string()}\n"
                     f"every thread that waited, task end -> it ran on (us):\n{every.to_string()}")
    return "\n".join(texts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("experiment", type=Path, nargs="?")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--devices", default=None)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--report", type=Path, metavar="FOLDER")
    args = ap.parse_args(argv)
    if args.report:
        print(report(args.report))
        return 0
    if args.experiment is None or args.out is None:
        ap.error("give EXPERIMENT and --out, or --report FOLDER")
    from mgpusim.model.toml_checks import int_list
    print(measure(args.experiment, args.overrides, int_list(args.devices, "--devices"), args.out))
    print(report(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
