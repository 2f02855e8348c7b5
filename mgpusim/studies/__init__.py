"""Studies: named sets of configurations measured for real, a calibration and a validation.

:mod:`.study_file` reads a study file; :mod:`.measuring` measures it on Vulkan; :mod:`.pipeline`
runs the steps measure -> calibrate -> validate -> report; :mod:`.page` writes its report page
and :mod:`.floor` the replay floor between two sets of runs. The lavapipe main job
(`experiments/lavapipe/study.toml`) and the NVIDIA validations (`experiments/h200/study.toml`,
`experiments/h100/study.toml`) are studies.

The names below load on first use: a command that needs one module of this package (`mgpusim
study floor` needs :mod:`.floor`) does not pay for the calibration and report code.
"""
from __future__ import annotations

import importlib
from typing import Any

_API = {"Entry": "study_file", "Study": "study_file", "load_study": "study_file",
        "calibrate": "pipeline", "load_runs": "pipeline", "run": "pipeline", "validate": "pipeline",
        "write_report": "pipeline"}
__all__ = sorted(_API)


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module(f"mgpusim.studies.{_API[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mgpusim.studies' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
