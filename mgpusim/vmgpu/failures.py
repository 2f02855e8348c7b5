"""The one kind of error the vmgpu measuring tool raises, with a message a person can act on.

Why: a measurement that fails half-way must say which input or which run failed and leave no
table behind that looks complete; callers catch this one class and print its message.
"""
from __future__ import annotations


class VmgpuMeasureError(Exception):
    """A measurement that cannot go on: a bad build folder, a bad option, or a failed run."""


class NotABuildError(VmgpuMeasureError):
    """The folder given as a vmgpu build folder is not one (no executable, no shaders)."""


class RunFailedError(VmgpuMeasureError):
    """One vmgpu run crashed, timed out, or printed no frame times; `run` names it."""

    def __init__(self, run: str, reason: str, tail: str = "") -> None:
        self.run = run
        self.reason = reason
        self.tail = tail
        message = f"vmgpu run {run} failed: {reason}"
        if tail:
            message += f"\n--- last output of that run ---\n{tail}"
        super().__init__(message)
