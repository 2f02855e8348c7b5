"""The Vulkan runner: executes the simulator's FrameProgram on real devices and
returns a trace in the simulator's schema; see docs/runner.md.

    run_experiment(exp, devices=None, lp_threads=None, host_threads=None) -> RunResult
    run_program(program, gpus, host_threads=1, prewarm_frames=None) -> RunResult

Importing this package loads the Vulkan binding lazily (only when a run starts).
"""
from __future__ import annotations

from typing import Any

__all__ = ["run_experiment", "run_program", "RunResult"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from mgpusim.real.runner import execute  # noqa: PLC0415
        return getattr(execute, name)
    raise AttributeError(name)
