"""Studies: named sets of configurations measured for real, a calibration and a validation.

:mod:`.spec` reads a study file; :mod:`.measure` measures it on Vulkan; :mod:`.pipeline` runs
the steps measure -> calibrate -> validate -> report. The lavapipe main job
(`experiments/lavapipe/study.toml`) and the NVIDIA validations (`experiments/h200/study.toml`,
`experiments/h100/study.toml`) are studies.

The names below load on first use: a command that needs one module of this package (`mgpusim
sweep` needs :mod:`.sweep_grid`) does not pay for the calibration and report code.
"""
from __future__ import annotations

import importlib
from typing import Any

_API = {"Entry": "spec", "Study": "spec", "load_study": "spec", "calibrate": "steps",
        "load_runs": "steps", "run": "steps", "validate": "steps", "write_report": "steps"}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module(f"mgpusim.studies.{_API[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mgpusim.studies' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
