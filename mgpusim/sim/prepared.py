"""What `simulate()` derives from an experiment before the model runs, kept per experiment.

Why: a script or notebook simulates one loaded experiment again and again (other fidelity
levels, effects forced on or off, a progress bar): its program, the effects each level
chooses and the analytic recurrence's precomputed task graph are the same every time, and
building them costs more than a short run itself. They are pure functions of the experiment
(a frozen object: `dataclasses.replace` makes a new one, with nothing cached), so each is
built once per experiment object and reused. An entry lives as long as its experiment: it is
dropped when the experiment is garbage-collected. Nothing here is a result: every call still
runs the model.
"""
from __future__ import annotations

import weakref
from typing import Any, Callable, Hashable

#: id(experiment) -> {what: value}; an entry is removed when its experiment is collected
_STORE: dict[int, dict[Hashable, Any]] = {}
_MISSING = object()


def cached(owner: object, what: Hashable, make: Callable[[], Any]) -> Any:
    """`make()` once per `owner` object and `what`; later calls return the same value. A
    `make` that raises caches nothing (the next call raises again)."""
    entry = _STORE.get(id(owner))
    if entry is None:
        entry = _STORE[id(owner)] = {}
        weakref.finalize(owner, _STORE.pop, id(owner), None)
    value = entry.get(what, _MISSING)
    if value is _MISSING:
        value = entry[what] = make()
    return value

