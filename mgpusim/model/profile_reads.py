"""Which profile values a run reads: so that a ``profile.`` override the model never reads is
refused as unused, not reported as a what-if that changed nothing.

Why reads, not effects: an override of a value the model reads may change nothing (a link
faster than the copies need), and that is an answer; one of a value it never reads for this
experiment (host memory bandwidth where host copies are work on CPU-emulated GPUs' cores, a
pass kind's cost where the scene has no such pass) gives the unchanged figures as if they
were the what-if's. The model cannot tell the two apart from its output, so it is watched:
:func:`recording` copies a profile into objects that note each field and mapping key read,
into the set given to the innermost :func:`reading` block, while it is on (the model's
build and run, the choice of its effects: a value that switches an effect off is used; not
validation or reports, which read every value whether the model uses it or not), by path
(``host.memory_bandwidth_gbps``, ``gpus.*.costs.fragment_loop.fixed_ns``: every GPU is
``gpus.*``). :func:`unused` maps the user's override keys onto those paths.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, Iterator, Sequence

from mgpusim.model.profile import HardwareProfile

#: Nesting of reading(reads) (on: the set reads go to) and not_reading() (off: None) blocks;
#: recording happens into the innermost's set. Why the set is the block's and not the copy's:
#: one recording copy of a profile serves every experiment that shares the profile (a sweep's
#: points), each run noting its own reads.
_STATE: list[set[str] | None] = []


@contextlib.contextmanager
def reading(reads: set[str]) -> Iterator[None]:
    """Record reads of :func:`recording` profiles inside this block, into `reads`."""
    _STATE.append(reads)
    try:
        yield
    finally:
        _STATE.pop()


@contextlib.contextmanager
def not_reading() -> Iterator[None]:
    """Inside a :func:`reading` block: reads that do not make a value used (a channel built
    only to be reported), not recorded."""
    _STATE.append(None)
    try:
        yield
    finally:
        _STATE.pop()


def _note(path: str) -> None:
    """`path` read: noted where the innermost block records."""
    if _STATE and _STATE[-1] is not None:
        _STATE[-1].add(path)


class RecordingMapping(Mapping):
    """A read-only mapping that notes `path.key` for each key read."""

    def __init__(self, data: Mapping[str, Any], path: str):
        self._data, self._path = data, path

    def __getitem__(self, key: str) -> Any:
        _note(f"{self._path}.{key}")
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __contains__(self, key: object) -> bool:
        _note(f"{self._path}.{key}")
        return key in self._data

    def __repr__(self) -> str:
        return repr(dict(self._data))


@functools.cache
def _recording_class(cls: type, path: str) -> type:
    """A subclass of dataclass `cls` whose instances note `path.<field>` on each field read
    (one class per path, shared by every copy: `dataclasses.replace` keeps recording)."""
    names = frozenset(f.name for f in dataclasses.fields(cls))
    paths = {name: f"{path}.{name}" if path else name for name in names}
    state = _STATE

    def __getattribute__(self: Any, name: str) -> Any:  # noqa: N807 - the hook itself
        if name in names and state and state[-1] is not None:
            state[-1].add(paths[name])
        return object.__getattribute__(self, name)

    return type(f"Recording{cls.__name__}", (cls,), {"__getattribute__": __getattribute__,
                                                      "__module__": __name__})


def recording(profile: HardwareProfile) -> HardwareProfile:
    """A copy of `profile` equal in every value, whose reads are noted into the set of the
    :func:`reading` block they happen in (see the module doc)."""
    return _copy(profile, "")


def _copy(value: Any, path: str) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        cls = _recording_class(type(value), path)
        kwargs = {f.name: _copy(getattr(value, f.name), _join(path, f.name))
                  for f in dataclasses.fields(value) if f.init}
        return cls(**kwargs)
    if isinstance(value, tuple) and path in ("gpus", "peer_links"):
        return tuple(_copy(v, f"{path}.*") for v in value)
    if isinstance(value, Mapping):
        return RecordingMapping({k: _copy(v, f"{path}.{k}") for k, v in value.items()}, path)
    return value


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def read_paths(key: str) -> list[str] | None:
    """The read paths an override key (relative to the profile) sets, any one of which read
    makes it used; None for keys that are not checked (names, counts, provenance, standard
    errors: a report's, not the model's)."""
    parts = key.split(".")
    if parts[0] == "peer_mesh" and len(parts) == 2:
        return [f"peer_links.*.{parts[1]}"]
    if parts[0] not in ("host", "gpus", "peer_links") or len(parts) < 2:
        return None
    if parts[0] in ("gpus", "peer_links"):
        parts[1] = "*"
        if len(parts) < 3 or parts[2] in ("name", "count"):
            return None
    if parts[0] == "gpus" and parts[2] == "costs" and len(parts) >= 5:
        if parts[4] == "stderr":
            return None
        if parts[4].startswith("ns_per_"):
            parts[4:5] = ["ns_per", parts[4].removeprefix("ns_per_")]
    if parts[0] == "gpus" and parts[2] == "copy" and len(parts) == 5 and parts[4].endswith("_gbps"):
        parts[4:5] = ["caps_gbps", parts[4].removesuffix("_gbps")]
    if parts[0] == "gpus" and parts[2] == "queue_overlap" and len(parts) == 5:
        parts[2] = "overlap_by_kind"
    if parts[0] == "gpus" and parts[2] == "link" and len(parts) == 4 and parts[3] in ("pcie_gen", "lanes"):
        # where the link gives measured rates they are scaled by gen and lanes (load_profile)
        return [f"gpus.*.link.{name}" for name in ("pcie_gen", "lanes", "h2d_gbps", "d2h_gbps")]
    return [".".join(parts)]


def unused(keys: Mapping[str, Any], reads: set[str]) -> list[str]:
    """The override keys (``profile.`` included) none of whose read paths (or a value under
    one: a table given whole) the run read."""
    out = []
    for key in keys:
        paths = read_paths(key.removeprefix("profile."))
        if paths is None:
            continue
        if not any(r == p or r.startswith(p + ".") for p in paths for r in reads):
            out.append(key)
    return out


def outside_shipped(overrides: Mapping[str, Any], profiles: Sequence[HardwareProfile]) -> list[str]:
    """One warning per numeric ``profile.`` override whose value lies outside the range that
    value takes over `profiles` (the shipped ones: every GPU, defaults included), e.g. a
    bandwidth a million times below any measured one. Why: such a what-if extrapolates where
    no profile's measurement or estimate stands behind it; its figures hold only as far as the
    model's linear costs and rates do. A value no profile has (a pass kind's cost none gives),
    or one every profile has alike (a what-if factor such as `speed`, 1 in each), is not
    judged: there is no range to be outside of."""
    out = []
    for key, value in overrides.items():
        paths = read_paths(key.removeprefix("profile.")) if key.startswith("profile.") else None
        if not paths or not _number(value):
            continue
        span = _span(profiles, paths[0])
        if span is not None and not span[0] <= value <= span[1]:
            out.append(f"{key} = {value:g} lies outside every shipped profile's value "
                       f"({span[0]:g} to {span[1]:g} in hardware_profiles/): the results "
                       "extrapolate beyond any machine a profile describes")
    return out


#: Each read path's span over a sequence of profiles, by the sequence's identity (profiles
#: hold mappings, so they cannot be hashed): a sweep judges one key at each of 10^4 points.
_SPANS: dict[tuple[int, str], tuple[Sequence[HardwareProfile], tuple[float, float] | None]] = {}


def _span(profiles: Sequence[HardwareProfile], path: str) -> tuple[float, float] | None:
    """(lowest, highest) of the values at `path` over `profiles`, None where they give none or
    all alike; kept while the same sequence is asked again (the shipped profiles, read once)."""
    key = (id(profiles), path)
    held = _SPANS.get(key)
    if held is not None and held[0] is profiles:
        return held[1]
    known = [v for p in profiles for v in _values(p, path.split(".")) if _number(v)]
    span = (min(known), max(known)) if known and min(known) < max(known) else None
    _SPANS[key] = (profiles, span)
    return span


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _values(node: Any, parts: Sequence[str]) -> list[Any]:
    """The values at a read path (``*``: every GPU or peer link) in a parsed profile."""
    if not parts:
        return [node]
    head, rest = parts[0], parts[1:]
    if head == "*" and isinstance(node, tuple):
        return [v for item in node for v in _values(item, rest)]
    if isinstance(node, Mapping):
        return _values(node[head], rest) if head in node else []
    if dataclasses.is_dataclass(node) and head in {f.name for f in dataclasses.fields(node)}:
        return _values(getattr(node, head), rest)
    return []


@functools.lru_cache(maxsize=1)
def shipped_profiles() -> tuple[HardwareProfile, ...]:
    """The shipped hardware profiles (`hardware_profiles/*.toml`), parsed once per process:
    the ranges :func:`outside_shipped` judges against, read from the files at run time so that
    a profile added there widens them (one that does not load is left out)."""
    from mgpusim.model.errors import InputError  # noqa: PLC0415
    from mgpusim.model.profile import load_profile  # noqa: PLC0415
    from mgpusim.model.shipped_files import shipped_dir  # noqa: PLC0415 - read only when judged

    out = []
    for path in sorted(shipped_dir("hardware_profiles").glob("*.toml")):
        with contextlib.suppress(InputError):
            out.append(load_profile(path))
    return tuple(out)
