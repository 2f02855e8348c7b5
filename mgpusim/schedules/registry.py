"""The schedules by name: each schedule module registers its builder and options here, and an
experiment's [schedule] table is checked against the registered schedule's options.

Why a module of its own: the schedules import the program vocabulary (`base`), and the
registry loads the schedules; keeping it above `base` leaves no import cycle.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping

from mgpusim.model import limits as L
from mgpusim.model.profile import HardwareProfile
from mgpusim.model.scene import Scene
from mgpusim.model.toml_checks import Table
from mgpusim.schedules.base import MAX_REFRESH_HZ, FrameProgram

#: The built-in schedules' modules (each registers itself when imported).
_MODULES = ("five_step", "afr", "pipelining", "xr", "particles")


def ensure_loaded() -> None:
    """Import every built-in schedule, so that SCHEDULES lists them all."""
    for name in _MODULES:
        importlib.import_module(f"mgpusim.schedules.{name}")


@dataclass(frozen=True)
class Option:
    """A schedule-specific key of the experiment's [schedule] table."""

    kind: type
    default: Any
    doc: str
    choices: tuple[Any, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    #: what the upper bound protects (said in the message that refuses a larger value)
    why: str = ""


@dataclass(frozen=True)
class ScheduleConfig:
    name: str
    gpus: int
    frames: int
    warmup_frames: int
    frames_in_flight: int
    options: Mapping[str, Any]
    refresh_hz: float = 0.0
    cpu_frame_us: float = 0.0

    def opt(self, key: str) -> Any:
        return self.options[key]


Builder = Callable[[ScheduleConfig, Scene, HardwareProfile], FrameProgram]


@dataclass(frozen=True)
class ScheduleDef:
    name: str
    build: Builder
    options: Mapping[str, Option]
    doc: str


SCHEDULES: dict[str, ScheduleDef] = {}


def register(name: str, doc: str, options: Mapping[str, Option] | None = None) -> Callable[[Builder], Builder]:
    def wrap(build: Builder) -> Builder:
        SCHEDULES[name] = ScheduleDef(name, build, MappingProxyType(dict(options or {})), doc)
        return build
    return wrap


def parse_schedule_config(t: Table) -> ScheduleConfig:
    ensure_loaded()
    name = t.get("name", str, choices=SCHEDULES.keys())
    sdef = SCHEDULES[name]
    options = {key: t.get(key, o.kind, o.default, choices=o.choices, minimum=o.minimum,
                          maximum=o.maximum, why=o.why)
               for key, o in sdef.options.items()}
    cfg = ScheduleConfig(
        name=name,
        gpus=t.get("gpus", int, 1, minimum=1, maximum=L.MAX_GPUS, why=L.WHY_ALLOC),
        frames=t.get("frames", int, 60, minimum=1, maximum=L.MAX_FRAMES, why=L.WHY_FRAMES),
        warmup_frames=t.get("warmup_frames", int, 5, minimum=0),
        frames_in_flight=t.get("frames_in_flight", int, 2, minimum=1, maximum=L.MAX_BUFFERS,
                               why=L.WHY_ALLOC),
        options=MappingProxyType(options),
        refresh_hz=t.get("refresh_hz", float, 0.0, minimum=0.0, maximum=MAX_REFRESH_HZ,
                         why="faster than any display"),
        cpu_frame_us=t.get("cpu_frame_us", float, 0.0, minimum=0.0,
                           maximum=L.MAX_TASK_NS / 1000, why=L.WHY_TIME),
    )
    t.finish()
    if cfg.warmup_frames >= cfg.frames:
        raise t.error("warmup_frames", f"must be < frames ({cfg.frames}), got {cfg.warmup_frames}")
    return cfg
