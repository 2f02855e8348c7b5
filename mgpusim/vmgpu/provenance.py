"""PROVENANCE.md of a vmgpu measurement: what was measured, with what, on what machine, how.

Why: frame times of a patched 2018 renderer on a software rasteriser mean something only with
the renderer's commits, the patch's digest, the driver's and Qt's versions, the CPU and how loaded
it was, and the exact command; a table without these cannot be compared with a later one.
"""
from __future__ import annotations

import hashlib
import os
import platform
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from mgpusim.vmgpu import build_folder
from mgpusim.vmgpu.build_folder import Build
from mgpusim.vmgpu.campaign import HALF_RULE, Grid, Settings

PACKAGES = ("mesa-vulkan-drivers", "libqt5gui5", "qtbase5-dev", "xvfb", "libvulkan1",
            "libshaderc1", "libglm-dev")


@dataclass(frozen=True)
class Context:
    """What is known before the first run: the build, its commits, the patch, the machine."""

    build: Build
    vmgpu_commit: str
    bp_commit: str
    patch: Path | None
    patch_sha256: str
    packages: dict[str, str]
    cpu_model: str
    cores: int
    load_start: tuple[float, float, float]
    command: str
    started: str
    probe_module: str
    driver: str = "lavapipe"
    gpu_report: str = ""


def sha256(path: Path | None) -> str:
    """The file's SHA-256, or 'none given'."""
    if path is None:
        return "none given"
    return hashlib.sha256(path.read_bytes()).hexdigest()


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str]:
    """Debian's installed version of each package ('not installed' where dpkg knows none)."""
    out = {}
    for name in names:
        try:
            done = subprocess.run(["dpkg-query", "-W", "-f", "${Version}", name],
                                  capture_output=True, text=True, timeout=30, check=False)
            out[name] = done.stdout.strip() if done.returncode == 0 and done.stdout.strip() \
                else "not installed"
        except OSError:
            out[name] = "unknown (no dpkg-query)"
    return out


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (the platform's name elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def nvidia_smi() -> str:
    """The card and driver as nvidia-smi reports them (its GPU list and a CSV of name, driver,
    memory and clocks), or why there is no report."""
    parts = []
    for args in (["-L"], ["--query-gpu=name,driver_version,memory.total,clocks.max.graphics,"
                          "pci.bus_id", "--format=csv"]):
        try:
            done = subprocess.run(["nvidia-smi", *args], capture_output=True, text=True,
                                  timeout=60, check=False)
        except (OSError, subprocess.TimeoutExpired) as error:
            return f"no nvidia-smi report ({error})"
        if done.returncode != 0:
            return f"no nvidia-smi report (exit status {done.returncode}: {done.stderr.strip()})"
        parts.append(done.stdout.strip())
    return "\n".join(parts)


def context(build: Build, patch: Path | None, probe_module: str, argv: list[str],
            driver: str = "lavapipe") -> Context:
    """The context now (read before the runs start); with the native driver, nvidia-smi's
    report of the card and driver too."""
    return Context(build=build, vmgpu_commit=build_folder.commit(build.source),
                   bp_commit=build_folder.commit(build.source / "bp" if build.source else None),
                   patch=patch.resolve() if patch else None, patch_sha256=sha256(patch),
                   packages=package_versions(), cpu_model=cpu_model(), cores=os.cpu_count() or 0,
                   load_start=os.getloadavg(), command=" ".join(shlex.quote(a) for a in argv),
                   started=time.strftime("%Y-%m-%d %H:%M:%S %Z"), probe_module=probe_module,
                   driver=driver, gpu_report=nvidia_smi() if driver == "native" else "")


def text(ctx: Context, grid: Grid, settings: Settings, runs: pd.DataFrame, frames: pd.DataFrame,
         end_probe: dict[str, float], probe_errors: list[str]) -> str:
    """The whole PROVENANCE.md."""
    on = "lavapipe" if ctx.driver == "lavapipe" else "the machine's own Vulkan driver"
    simulate = "simulated GPUs (`--simulate-mgpu`: VkDevices on one physical device)" \
        if grid.simulate else "real GPUs (no `--simulate-mgpu`: one physical device each)"
    lines = [f"# vmgpu on {ctx.driver}: provenance", "",
             f"Measured {ctx.started} to {time.strftime('%Y-%m-%d %H:%M:%S %Z')} by "
             "`python -m mgpusim.vmgpu`.", "", "## What ran", "",
             f"- vmgpu commit: `{ctx.vmgpu_commit}`; bp (its submodule) commit: `{ctx.bp_commit}`"
             " ('+dirty': the checkout carries the patch)",
             f"- patch file: `{ctx.patch}` sha256 `{ctx.patch_sha256}` (kept outside this "
             "repository)",
             f"- build folder: `{ctx.build.folder}` (CMake build type {ctx.build.build_type})",
             "- Debian packages: " + ", ".join(f"{k} {v}" for k, v in ctx.packages.items()),
             f"- Python {sys.version.split()[0]}, kernel {platform.release()}",
             f"- Vulkan driver (`--driver {ctx.driver}`): {on}; {simulate}", "",
             "## Machine", "",
             f"- CPU: {ctx.cpu_model}, {ctx.cores} cores",
             f"- load average at start: {' / '.join(f'{v:.2f}' for v in ctx.load_start)} "
             f"(1/5/15 min); at end: {' / '.join(f'{v:.2f}' for v in os.getloadavg())}",
             "- per run (runs.parquet): load_before/after (1-minute load average; it counts "
             "vmgpu's own rendering threads too), other_cores (other processes' mean CPU use: "
             "the machine's busy time less vmgpu's and Xvfb's), steal_cores, vmgpu_cores, "
             "xvfb_cpu_s",
             *([] if not ctx.gpu_report else
               ["- GPU (nvidia-smi):", "", "```", ctx.gpu_report, "```", ""]),
             f"- speed probe: `{ctx.probe_module}` (Prober, fragment loop + mesh on one lavapipe "
             f"GPU) before each run (probe_fragment_ms, probe_mesh_ms); after the last run: "
             + ", ".join(f"{k} {v:.3f} ms" for k, v in end_probe.items()), ""]
    lines += [f"- probe failures: {e}" for e in probe_errors]
    lines += _method(grid, settings, ctx.command, on, simulate)
    lines += _summary(runs, frames)
    return "\n".join(lines) + "\n"


def _method(grid: Grid, settings: Settings, command: str, on: str = "lavapipe",
            simulate: str = "`--simulate-mgpu`") -> list[str]:
    res = ", ".join(f"{w}x{h}" for w, h in grid.resolutions)
    return ["## Method", "",
            f"- grid: strategies {', '.join(grid.strategies)}; GPUs "
            f"{', '.join(map(str, grid.gpus))} (single runs on 1, sort-first and sort-last on "
            f"2 or more: vmgpu runs them as single on 1); triangles "
            f"{', '.join(map(str, grid.triangles))} (a unit sphere, positions + normals, `-b`); "
            f"resolutions {res}",
            f"- each run: a fresh vmgpu process under one Xvfb, {on}, {simulate}, "
            f"{settings.frames} frames (VMGPU_EXIT_AFTER_FRAMES), the first {settings.warmup} "
            f"left out of the statistics (frames.parquet marks them `warmup`)",
            "- frame time: the patch's `frame_ms` line; period_ms = steady clock from the end of "
            "the previous frame's present to the end of this one's (bpQt::Window::frame), "
            "busy_ms = start of frame() to end of present, cpu_ms = process CPU time",
            f"- a stall: a frame over {settings.stall_factor:g} x its run's median; counted "
            f"(stalls, stall_ms), kept in the frames, not retried",
            f"- repeats: {settings.repeats}, interleaved: round-robin rounds over all "
            f"configurations, each round shuffled (seed {settings.seed}); no run retried",
            f"- halves (column `half`), decided before any run: {HALF_RULE}",
            f"- QT_QPA_UPDATE_IDLE_TIME: {os.environ.get('QT_QPA_UPDATE_IDLE_TIME', 'unset')} "
            f"(Qt's default 5 ms gap before each frame when unset); LP_NUM_THREADS: "
            f"{os.environ.get('LP_NUM_THREADS', 'unset (lavapipe: one thread per core)')}",
            "", "Command:", "", "```", command, "```", ""]


def _summary(runs: pd.DataFrame, frames: pd.DataFrame) -> list[str]:
    """Per configuration: the median of its runs' median frame times, their range and IQR."""
    grouped = runs.groupby(["strategy", "gpus", "triangles", "width", "height", "half"],
                           sort=True)
    lines = ["## Summary (per configuration, over its repeats)", "",
             "| strategy | GPUs | triangles | resolution | half | median ms | runs' medians | "
             "median IQR ms | stalls |", "|---|---|---|---|---|---|---|---|---|"]
    for (strategy, gpus, tris, w, h, half), g in grouped:
        lines.append(f"| {strategy} | {gpus} | {tris} | {w}x{h} | {half} | "
                     f"{g['median_ms'].median():.2f} | {g['median_ms'].min():.2f}-"
                     f"{g['median_ms'].max():.2f} | {g['iqr_ms'].median():.2f} | "
                     f"{int(g['stalls'].sum())} |")
    return lines + ["", f"Columns of runs.parquet: {', '.join(runs.columns)}.", "",
                    f"Columns of frames.parquet: {', '.join(frames.columns)} (join on `run`).", ""]
