"""One vmgpu run: a configuration, the command line and environment that run it, and what the
machine did around it (load average, other processes' CPU, vmgpu's and Xvfb's own CPU time).

Why record the machine per run: this 2-core machine is shared and its speed moves within
minutes; no run is retried, so each run carries the noise it was measured under.
"""
from __future__ import annotations

import math
import os
import resource
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from mgpusim.measure import host_load
from mgpusim.vmgpu.build_folder import Build
from mgpusim.vmgpu.failures import RunFailedError

STRATEGIES = ("single", "sort-first", "sort-last")
DRIVERS = ("lavapipe", "native")
LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")


@dataclass(frozen=True)
class Config:
    """One point of the grid: strategy, GPUs, triangles of the sphere, resolution; `simulate`:
    the GPUs are VkDevices on one physical device (`--simulate-mgpu`), else each is a GPU."""

    strategy: str
    gpus: int
    triangles: int
    width: int
    height: int
    simulate: bool = True

    @property
    def key(self) -> str:
        return f"{self.strategy}-x{self.gpus}-{self.triangles}-{self.width}x{self.height}"

    def arguments(self, mesh: Path) -> list[str]:
        """vmgpu's options: basic mode (positions + normals), the strategy, the GPU count (as
        simulated devices on one physical device unless `simulate` is off), the window size and
        the mesh."""
        simulate = ["--simulate-mgpu"] if self.simulate else []
        return ["-b", "-s", self.strategy, "-c", str(self.gpus), *simulate,
                "-r", f"{self.width}x{self.height}", "-p", str(mesh)]


@dataclass
class RunRecord:
    """A finished vmgpu process: its output, exit status, times and the machine around it."""

    text: str
    returncode: int
    wall_s: float
    vmgpu_cpu_s: float
    xvfb_cpu_s: float
    other_cores: float
    steal_cores: float
    load_before: float
    load_after: float
    unix_start: float


def environment(display: str, frames: int, runtime_dir: Path,
                driver: str = "lavapipe") -> dict[str, str]:
    """The run's environment: this process's, plus the X display, Qt's xcb platform, and the
    measuring aid's frame log and frame count. Driver 'lavapipe': lavapipe as the only Vulkan
    driver (where its ICD is installed); 'native': the Vulkan driver variables (VK_ICD_FILENAMES,
    VK_DRIVER_FILES) are left as this process has them, so the loader finds the machine's own."""
    if driver not in DRIVERS:
        raise ValueError(f"driver must be one of {DRIVERS}, got {driver!r}")
    env = dict(os.environ)
    env.update({"DISPLAY": display, "QT_QPA_PLATFORM": "xcb", "VMGPU_FRAME_LOG": "1",
                "VMGPU_EXIT_AFTER_FRAMES": str(frames), "XDG_RUNTIME_DIR": str(runtime_dir)})
    if driver == "lavapipe" and LAVAPIPE_ICD.is_file():
        env["VK_ICD_FILENAMES"] = str(LAVAPIPE_ICD)
    return env


def run(build: Build, config: Config, mesh: Path, display: str, frames: int, timeout_s: float,
        run_label: str, xvfb_pid: int | None = None, driver: str = "lavapipe") -> RunRecord:
    """Run vmgpu once for `frames` frames in its build folder (it loads `spv/` from there) on
    `driver`; RunFailedError naming `run_label` if it does not finish within `timeout_s`."""
    with tempfile.TemporaryDirectory(prefix="vmgpu-xdg-") as runtime:
        os.chmod(runtime, 0o700)
        env = environment(display, frames, Path(runtime), driver)
        before = _sample(xvfb_pid)
        load_before = os.getloadavg()[0]
        done = _run_process([str(build.executable), *config.arguments(mesh)], build.folder,
                            env, timeout_s, frames, run_label)
        after = _sample(xvfb_pid)
    return _record(done, before, after, load_before)


def _run_process(command: list[str], cwd: Path, env: dict[str, str], timeout_s: float,
                 frames: int, run_label: str) -> subprocess.CompletedProcess[str]:
    """Run `command` in its own process group; on the timeout the whole group is killed (a
    script's children too, so its pipes close) and RunFailedError is raised."""
    try:
        process = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True, errors="replace",
                                   start_new_session=True)
    except OSError as error:
        raise RunFailedError(run_label, f"it could not be started: {error}") from None
    try:
        stdout, stderr = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        raise RunFailedError(run_label, f"it did not finish {frames} frames in {timeout_s:g} s "
                                        f"(killed)", (stdout + stderr)[-2000:]) from None
    return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)


@dataclass(frozen=True)
class _Sample:
    wall: float
    unix: float
    busy: float
    steal: float
    children: float
    xvfb: float


def _sample(xvfb_pid: int | None) -> _Sample:
    """The machine's busy and steal CPU seconds, the waited-for children's CPU seconds, and
    Xvfb's, now."""
    machine = host_load.sample()
    busy, steal = (machine.busy_s, machine.steal_s) if machine is not None else (math.nan, math.nan)
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return _Sample(wall=time.monotonic(), unix=time.time(), busy=busy, steal=steal,
                   children=usage.ru_utime + usage.ru_stime, xvfb=_process_cpu(xvfb_pid))


def _process_cpu(pid: int | None) -> float:
    """A live process's user + system CPU seconds (NaN where it cannot be read)."""
    if pid is None:
        return float("nan")
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def _record(done: subprocess.CompletedProcess[str], before: _Sample, after: _Sample,
            load_before: float) -> RunRecord:
    wall = after.wall - before.wall
    vmgpu_cpu = after.children - before.children
    xvfb_cpu = after.xvfb - before.xvfb
    other = (after.busy - before.busy) - vmgpu_cpu - (0.0 if math.isnan(xvfb_cpu) else xvfb_cpu)
    return RunRecord(text=(done.stdout or "") + "\n" + (done.stderr or ""),
                     returncode=done.returncode, wall_s=wall, vmgpu_cpu_s=vmgpu_cpu,
                     xvfb_cpu_s=xvfb_cpu, other_cores=max(0.0, other) / wall,
                     steal_cores=(after.steal - before.steal) / wall,
                     load_before=load_before, load_after=os.getloadavg()[0],
                     unix_start=before.unix)
