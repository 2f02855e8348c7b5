"""Schedules: each one builds the work of a frame (a FrameProgram) from a scene and a profile.

`registry` holds them by name; `base` the program vocabulary they share; `experiment` reads an
experiment file; `program` builds an experiment's program; `memory_check` refuses one that
does not fit the GPUs' memory.
"""
from __future__ import annotations

from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.registry import SCHEDULES, ScheduleConfig, ScheduleDef, ensure_loaded, register

__all__ = ["SCHEDULES", "FrameProgram", "ScheduleConfig", "ScheduleDef", "register", "ensure_loaded"]
