"""mgpusim: predict how a rendering workload behaves on several GPUs.

Python API::

    import mgpusim
    exp = mgpusim.load_experiment("experiments/sort_first_tc1.toml", overrides={"schedule.gpus": 3})
    result = mgpusim.simulate(exp)
    result.summary["frame_time_ms"], result.trace, result.frames
    table = mgpusim.sweep("experiments/sort_first_tc1.toml", {"schedule.gpus": [1, 2, 3]}, out="out/sweep")
"""
from __future__ import annotations

import importlib
from typing import Any

#: The public API, by the module that holds each name. Loaded on first use, so that a command
#: (or `mgpusim --version`) pays only for what it imports.
_API = {
    "InputError": "mgpusim.model.errors", "MgpusimError": "mgpusim.model.errors",
    "ScheduleError": "mgpusim.model.errors",
    "HardwareProfile": "mgpusim.model.profile", "load_profile": "mgpusim.model.profile",
    "Result": "mgpusim.results.summary",
    "Experiment": "mgpusim.schedules.experiment", "load_experiment": "mgpusim.schedules.experiment",
    "simulate": "mgpusim.sim.simulation",
    "sweep": "mgpusim.sweeps.grid",
}
__all__ = sorted(_API)
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _API:
        value = getattr(importlib.import_module(_API[name]), name)
        globals()[name] = value  # once loaded, a plain attribute
        return value
    raise AttributeError(f"module 'mgpusim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
