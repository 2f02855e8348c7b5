"""vmgpu's output, read: the frame log of the measuring aid, the GPUs it opened, the triangles it
loaded; one run's frame times summarised; a run that crashed or printed no frames, refused.

The patched vmgpu (environment variable `VMGPU_FRAME_LOG=1`) prints, on stderr, one line per
frame after the frame's present returned::

    frame_log period 1 exit_after 200 clock steady
    frame_ms <index> <period_ms> <busy_ms> <cpu_ms>
    frames_done 200

`period_ms` is the steady (monotonic) clock from the end of the previous frame's present to the
end of this one's (what the FPS counter counts, Qt's update gap included), `busy_ms` from the
start of `bpQt::Window::frame()` to the end of its present, `cpu_ms` the process's CPU time over
the period. With `VMGPU_FRAME_LOG=N` (N > 1) it prints `frame_ms_mean <last index> <period>
<busy> <cpu> <N>`, means over N frames. A bare `frame_ms <index> <ms>` is read too (busy and CPU
then unknown). On stdout vmgpu prints `GPU<i>: <name>[vendor:device]` per device and
`Total triangle count is <n>.`, and bpQt's `\\rFramerate = <fps> FPS` every 50 frames.

Why parse and check here: every number of a run comes from these lines, and a run that printed
none, stopped early, or opened another number of GPUs than asked must fail loudly, naming the run,
rather than become a row of a table.
"""
from __future__ import annotations

import math
import re
import signal
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from mgpusim.vmgpu.failures import RunFailedError

FRAME = re.compile(r"^frame_ms (\d+) ([-+0-9.eE]+)(?: ([-+0-9.eE]+) ([-+0-9.eE]+))?\s*$", re.M)
FRAME_MEAN = re.compile(
    r"^frame_ms_mean (\d+) ([-+0-9.eE]+) ([-+0-9.eE]+) ([-+0-9.eE]+) (\d+)\s*$", re.M)
DONE = re.compile(r"^frames_done (\d+)\s*$", re.M)
GPU = re.compile(r"^GPU(\d+): (.*)$", re.M)
TRIANGLES = re.compile(r"Total triangle count is (\d+)\.")
FPS = re.compile(r"Framerate = ([0-9.eE+-]+) FPS")
#: A frame slower than this many times its run's median (after warm-up) is a stall.
STALL_FACTOR = 5.0
COLUMNS = ["frame", "period_ms", "busy_ms", "cpu_ms", "frames_in_line"]


@dataclass
class VmgpuLog:
    """What one run printed: its frame lines (one row each, `COLUMNS`), the GPUs it opened, the
    triangles it loaded, the frame count of `frames_done`, and bpQt's FPS prints."""

    frames: pd.DataFrame
    gpus: list[str] = field(default_factory=list)
    triangles: int | None = None
    frames_done: int | None = None
    fps: list[float] = field(default_factory=list)


def parse(text: str) -> VmgpuLog:
    """Read vmgpu's output (stdout and stderr together, in any order: the frame lines start
    their own lines, bpQt's carriage-return FPS prints are split off first)."""
    text = text.replace("\r", "\n")
    rows = [_frame_row(m) for m in FRAME.finditer(text)]
    rows += [_mean_row(m) for m in FRAME_MEAN.finditer(text)]
    frames = pd.DataFrame(rows, columns=COLUMNS).sort_values("frame", ignore_index=True)
    frames = frames.astype({"frame": "int64", "frames_in_line": "int64"})
    done = [int(m.group(1)) for m in DONE.finditer(text)]
    triangles = TRIANGLES.search(text)
    return VmgpuLog(frames=frames,
                    gpus=[m.group(2).strip() for m in GPU.finditer(text)],
                    triangles=int(triangles.group(1)) if triangles else None,
                    frames_done=done[-1] if done else None,
                    fps=[float(m.group(1)) for m in FPS.finditer(text)])


def _frame_row(m: re.Match[str]) -> list[float]:
    busy = float(m.group(3)) if m.group(3) else math.nan
    cpu = float(m.group(4)) if m.group(4) else math.nan
    return [int(m.group(1)), float(m.group(2)), busy, cpu, 1]


def _mean_row(m: re.Match[str]) -> list[float]:
    return [int(m.group(1)), float(m.group(2)), float(m.group(3)), float(m.group(4)),
            int(m.group(5))]


@dataclass(frozen=True)
class Expected:
    """What a run was asked for, to check its output against."""

    frames: int
    gpus: int
    triangles: int


def check(run: str, returncode: int, text: str, expected: Expected) -> VmgpuLog:
    """The parsed log of a run that finished as asked, else RunFailedError naming `run`: it
    crashed or exited non-zero, printed no frame times, stopped before `expected.frames`, or
    opened another number of GPUs or loaded another triangle count than asked."""
    tail = _tail(text)
    if returncode != 0:
        raise RunFailedError(run, _exit_reason(returncode), tail)
    log = parse(text)
    if log.frames.empty:
        raise RunFailedError(run, "it printed no frame times (no 'frame_ms' line: is this vmgpu "
                                  "built with the VMGPU_FRAME_LOG measuring aid?)", tail)
    frames = int(log.frames["frames_in_line"].sum())
    if log.frames_done != expected.frames or frames != expected.frames:
        raise RunFailedError(run, f"it printed {frames} frame times and frames_done "
                                  f"{log.frames_done}, expected {expected.frames}", tail)
    if len(log.gpus) != expected.gpus:
        raise RunFailedError(run, f"it opened {len(log.gpus)} GPUs, {expected.gpus} were asked "
                                  f"for", tail)
    if log.triangles != expected.triangles:
        raise RunFailedError(run, f"it loaded {log.triangles} triangles, the mesh has "
                                  f"{expected.triangles}", tail)
    return log


def _exit_reason(returncode: int) -> str:
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"it was killed by {name} (a crash)"
    return f"it exited with status {returncode}"


def _tail(text: str, lines: int = 15) -> str:
    return "\n".join(text.replace("\r", "\n").strip().splitlines()[-lines:])


def stalls(period_ms: pd.Series, factor: float = STALL_FACTOR) -> pd.Series:
    """Which frames took more than `factor` times the median of `period_ms` (a stall: the
    process was descheduled or the machine paused, not the renderer's steady cost)."""
    return period_ms > factor * float(period_ms.median())


def summary(frames: pd.DataFrame, warmup: int, factor: float = STALL_FACTOR) -> dict[str, float]:
    """One run's frame-time statistics over the frames after the first `warmup` (with mean
    lines, over those lines: their spread is then that of N-frame means): median, quartiles,
    IQR, mean, 90th percentile, max, the stalls and the medians of busy time, idle gap and CPU
    time.

    Why medians and IQR: on this shared machine a few frames stall for other processes; the
    median is the renderer's cost and the IQR its steadiness, the stalls are counted apart."""
    kept = frames[frames["frame"] >= warmup]
    if kept.empty:
        raise ValueError(f"no frames after the first {warmup}")
    period = kept["period_ms"]
    q25, q50, q75 = (float(np.percentile(period, q)) for q in (25, 50, 75))
    stalled = stalls(period, factor)
    return {"frames_measured": int(kept["frames_in_line"].sum()), "median_ms": q50,
            "q25_ms": q25, "q75_ms": q75, "iqr_ms": q75 - q25, "iqr_rel": (q75 - q25) / q50,
            "mean_ms": float(period.mean()), "p90_ms": float(np.percentile(period, 90)),
            "max_ms": float(period.max()), "stalls": int(stalled.sum()),
            "stall_ms": float(period[stalled].sum()),
            "busy_median_ms": float(kept["busy_ms"].median()),
            "gap_median_ms": float((kept["period_ms"] - kept["busy_ms"]).median()),
            "cpu_median_ms": float(kept["cpu_ms"].median()),
            "fps_median": 1000.0 / q50}
