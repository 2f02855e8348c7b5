"""The unused-override check of a sweep's points, on one recording copy per profile.

Why: :func:`~mgpusim.sim.simulation.simulate` refuses a ``profile.`` override the model never
reads, by running the model on a copy of the profile that notes each value read
(:func:`mgpusim.model.profile_reads.recording`), made once per experiment object. A sweep
loads a new experiment per point, so every point with profile overrides paid for a copy of
its whole profile: about 1 ms, a third of a cheap full-fidelity point. Its points share few
profiles (the loader hands out one object per distinct set of profile overrides), so
:func:`share_recording` makes the copy once per profile and empties its reads before each
point, and gives it to simulate() as the experiment's watched copy (simulate's cache per
experiment object, :mod:`mgpusim.sim.prepared`, under the key simulate looks it up by). The
run then reads the same copy of the same values and its reads are checked the same way, the
point's own reads only. Were simulate's key ever to change, it would make its own copy, as
before: slower, never different.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from typing import Any

from mgpusim.model.profile_reads import recording
from mgpusim.schedules.experiment import Experiment
from mgpusim.sim.prepared import cached

#: Recording copies kept (the most recently used): points come in grid order, so a profile
#: key's points are consecutive runs or a short cycle.
KEEP = 256
#: id(profile) -> (the profile, kept alive while its id is a key; its copy; the copy's reads)
_COPIES: "OrderedDict[int, tuple[Any, Any, set[str]]]" = OrderedDict()


def share_recording(exp: Experiment, fidelity: str) -> None:
    """Before ``simulate(exp, fidelity=fidelity)`` (no effects forced): give `exp` the shared
    recording copy of its profile, its reads emptied (nothing to do without profile overrides)."""
    if not exp.profile_overrides:
        return
    key = id(exp.profile)
    entry = _COPIES.get(key)
    if entry is None or entry[0] is not exp.profile:
        entry = _COPIES[key] = (exp.profile, *recording(exp.profile))
        while len(_COPIES) > KEEP:
            _COPIES.popitem(last=False)
    _COPIES.move_to_end(key)
    _, copy, reads = entry
    reads.clear()
    cached(exp, ("watched", fidelity, ()), lambda: (replace(exp, profile=copy), reads))
