"""Errors that reach the user as one clear line (the CLI prints them without a traceback)."""
from __future__ import annotations


class MgpusimError(Exception):
    """Base class of every error mgpusim reports to a user."""


class InputError(MgpusimError):
    """Bad input: names the file (if any), the field and what was expected."""

    def __init__(self, message: str, *, file: str | None = None, field: str | None = None):
        self.file = file
        self.field = field
        self.detail = message
        where = ": ".join(p for p in (file, field) if p)
        super().__init__(f"{where}: {message}" if where else message)


class TimeBoundError(InputError):
    """A task would last longer than the bound that keeps simulated time in int64: its cause
    is split between the experiment (the work) and the profile (the rates)."""


class ScheduleError(MgpusimError):
    """A schedule that can never finish (cycle, missing resource, blocked tasks)."""


class DependencyError(MgpusimError):
    """A dependency (package, driver, compiler) is missing; says how to install it."""


class UnsteadyMachineError(MgpusimError):
    """The machine's own speed moved more than the user allowed before a job began: its errors
    would measure the machine, not the model."""
