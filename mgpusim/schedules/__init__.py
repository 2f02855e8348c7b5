"""Schedule registry. Importing this package registers every built-in schedule."""
from __future__ import annotations

from .base import SCHEDULES, FrameProgram, ScheduleConfig, ScheduleDef, register

_MODULES = ("five_step", "afr", "pipelining", "xr", "particles")


def ensure_loaded() -> None:
    """Import the schedule modules (each registers itself)."""
    import importlib
    for name in _MODULES:
        importlib.import_module(f"{__name__}.{name}")


__all__ = ["SCHEDULES", "FrameProgram", "ScheduleConfig", "ScheduleDef", "register", "ensure_loaded"]
