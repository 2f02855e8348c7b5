"""One Xvfb X server on a free display for a whole measurement, stopped at its end.

Why: vmgpu opens a real Qt window (only Qt's xcb platform gives it a Vulkan instance), and this
machine has no screen. One server for all runs keeps its start-up out of the runs and its cost the
same for each; a display number that another server holds is skipped, never shared.
"""
from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path
from types import TracebackType

from mgpusim.vmgpu.failures import VmgpuMeasureError

FIRST_DISPLAY = 90
LAST_DISPLAY = 189
START_TIMEOUT_S = 15.0
SOCKETS = Path("/tmp/.X11-unix")


def free_display(first: int = FIRST_DISPLAY, last: int = LAST_DISPLAY) -> int:
    """The first display number in [first, last] with neither a lock file nor a socket."""
    for n in range(first, last + 1):
        if not Path(f"/tmp/.X{n}-lock").exists() and not (SOCKETS / f"X{n}").exists():
            return n
    raise VmgpuMeasureError(f"no free X display between :{first} and :{last}")


class Xvfb:
    """`with Xvfb(width, height) as display:` an X server on `display` (such as ':90') whose
    screen holds a `width` x `height` window, stopped on leaving."""

    def __init__(self, width: int, height: int) -> None:
        self.width = width
        self.height = height
        self.process: subprocess.Popen[bytes] | None = None
        self.display = ""

    def __enter__(self) -> str:
        exe = shutil.which("Xvfb")
        if exe is None:
            raise VmgpuMeasureError("Xvfb is not installed (Debian package xvfb); vmgpu needs an "
                                    "X display")
        for _ in range(5):  # another server may take the number between the check and the start
            number = free_display()
            if self._start(exe, number):
                return self.display
        raise VmgpuMeasureError("Xvfb did not start on any of five free displays")

    def _start(self, exe: str, number: int) -> bool:
        """Start Xvfb on `number`; True once its socket is there, False if it exited."""
        screen = f"{self.width + 64}x{self.height + 64}x24"
        self.process = subprocess.Popen([exe, f":{number}", "-screen", "0", screen, "-nolisten",
                                         "tcp", "-noreset"], stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                self.process = None
                return False
            if (SOCKETS / f"X{number}").exists():
                self.display = f":{number}"
                return True
            time.sleep(0.05)
        self.stop()
        raise VmgpuMeasureError(f"Xvfb on :{number} did not open its socket in "
                                f"{START_TIMEOUT_S:.0f} s")

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    def stop(self) -> None:
        """Stop the server (terminate, then kill after 5 s)."""
        if self.process is None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.process = None

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.stop()
