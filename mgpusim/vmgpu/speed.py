"""The project's speed probe between vmgpu runs, found wherever the package keeps it now.

Why: this machine's speed moves by tens of percent within minutes; the probe (a fragment loop
and a mesh on one lavapipe GPU, ~0.1 s once warm) measured just before each run says how fast the
machine was then, so each run's frame times can be read against it. The probe is the project's
own (`Prober` in the module `speed_probe`), used as it is; the package is being reorganised, so
the module is looked up by file name rather than by one fixed path.
"""
from __future__ import annotations

import importlib
import math
import os
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol

import mgpusim
from mgpusim.vmgpu.failures import VmgpuMeasureError

MODULE_FILE = "speed_probe.py"
PASSES = ("fragment_loop", "mesh")


class Probe(Protocol):
    """What the campaign needs of a probe: the passes' median times now, by pass name."""

    module_name: str
    errors: list[str]

    def measure(self) -> dict[str, float]: ...

    def close(self) -> None: ...


def find_module() -> ModuleType:
    """The package's speed-probe module (the first `speed_probe.py` under mgpusim/ that has a
    `Prober`)."""
    root = Path(mgpusim.__file__).resolve().parent
    for path in sorted(root.rglob(MODULE_FILE)):
        name = ".".join(["mgpusim", *path.relative_to(root).with_suffix("").parts])
        module = importlib.import_module(name)
        if hasattr(module, "Prober"):
            return module
    raise VmgpuMeasureError("the project's speed probe (a speed_probe.py with Prober) was not "
                            "found under mgpusim/; run with --no-probe to measure without it")


class ProjectProbe:
    """The project's `Prober` on one lavapipe GPU, opened once and kept for the whole campaign."""

    def __init__(self, threads: int | None = None) -> None:
        module = find_module()
        self.module_name = module.__name__
        try:
            self._prober: Any = module.Prober(threads or os.cpu_count() or 1)
            self._prober.__enter__()
        except Exception as error:  # noqa: BLE001 - any failure to open Vulkan here
            raise VmgpuMeasureError(f"the speed probe ({self.module_name}) could not open a "
                                    f"lavapipe GPU: {error}; run with --no-probe to measure "
                                    f"without it") from error
        self._count = 0
        self.errors: list[str] = []

    def measure(self) -> dict[str, float]:
        """The probe's median pass times (ms) now, by pass; NaN for a pass that failed."""
        self._count += 1
        try:
            rows = self._prober.probe(f"vmgpu probe {self._count}")
        except Exception as error:  # noqa: BLE001 - a failed probe is recorded, not fatal
            self.errors.append(f"probe {self._count}: {error}")
            return {p: math.nan for p in PASSES}
        return {row["pass"]: float(row["median_ms"]) for row in rows}

    def close(self) -> None:
        self._prober.__exit__(None, None, None)


class NoProbe:
    """No probe (`--no-probe`): every value NaN."""

    module_name = "none"
    errors: list[str] = []

    def measure(self) -> dict[str, float]:
        return {p: math.nan for p in PASSES}

    def close(self) -> None:
        return None
