"""`mgpusim advise`: which multi-GPU schedule, how many GPUs and which link suit a frame.

The search (:func:`search`) builds every option from one experiment (usually an imported
frame): sort-first with balanced tiles and sort-last (each with a host copy between staging
buffers or one shared host allocation), alternate-frame rendering (carrying the frame's
temporal input, if it has one), frame pipelining over every contiguous split point with 1 to 8
chunks per copy, and XR stereo (2 or 4 GPUs, weak or strong scaling) where the frame has two
views; on 2 to 8 GPUs, over PCIe 3/4/5 x8/x16 and NVLink. Each option is a set of overrides of
the experiment (`mgpusim simulate EXPERIMENT --set ...` reproduces it).

Every option runs first at the `analytic` level (no event simulation; milliseconds each). The
best of them by frame time, the best of each GPU count and of each schedule, and those on the
analytic Pareto front of frame time and latency are confirmed at `full` fidelity; the ranking
(frame time, then latency, then GPUs) and the Pareto front (frame time against latency) are
over the confirmed results. Where the analytic level is an optimistic bound (every
approximation it makes only speeds the model up: docs/fidelity.md), an option whose analytic
frame time is above the best confirmed frame time cannot beat it: :attr:`Advice.open` counts
the options below it that were not confirmed, so "the best" is proven when it is 0.

Pure: no file is written here (the command writes the report).
"""
from __future__ import annotations

import copy
import functools
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence, cast

import pandas as pd

from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.model.overrides import set_dotted, split_profile
from mgpusim.model.profile import HardwareProfile, load_profile
from mgpusim.model.scene import temporal_reads
from mgpusim.model.toml_checks import read_toml
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_experiment
from mgpusim.sim.simulation import simulate

#: Pipelining's chunks per copy, searched at every split point.
CHUNKS = tuple(range(1, 9))
#: Schedule keys every schedule takes (kept from the experiment when the schedule changes).
COMMON_KEYS = ("frames", "warmup_frames", "frames_in_flight", "refresh_hz", "cpu_frame_us")
#: Options confirmed at full fidelity by default, besides the analytic Pareto front.
CONFIRM = 24
#: Differences smaller than this share do not keep an option on the Pareto front.
PARETO_TOLERANCE = 0.01


@dataclass(frozen=True)
class Link:
    """A link every GPU of an option has: the profile's what-ifs that give it, and a source."""

    name: str
    overrides: Mapping[str, Any]
    source: str
    nvlink: bool = False


def _pcie(gen: int, lanes: int) -> Link:
    return Link(f"PCIe {gen}.0 x{lanes}", {"profile.gpus.*.link.pcie_gen": gen,
                                           "profile.gpus.*.link.lanes": lanes},
                "PCI-SIG: 0.985 GB/s per lane (3.0), doubling per generation; the profile's "
                "efficiency and latency (a measured rate scales by the nominal ratio)")


#: The links searched: PCIe generations and widths of current boards, and NVLink between every
#: pair of GPUs (a bridge for two workstation cards, NVLink 4 through NVSwitch), beside the
#: profile's own PCIe link.
LINKS: tuple[Link, ...] = (
    *(_pcie(gen, lanes) for gen in (3, 4, 5) for lanes in (8, 16)),
    Link("NVLink bridge 56 GB/s", {"profile.peer_mesh": {"bandwidth_gbps": 56.25, "latency_ns": 2000}},
         "NVIDIA RTX A6000 datasheet: NVLink bridge 112.5 GB/s both directions together; latency "
         "2 us (estimate)", nvlink=True),
    Link("NVLink 4 450 GB/s", {"profile.peer_mesh": {"bandwidth_gbps": 450.0, "latency_ns": 2000}},
         "NVIDIA H100 SXM5 datasheet: NVLink 900 GB/s both directions together; latency 2 us "
         "(estimate)", nvlink=True),
)


@dataclass(frozen=True)
class Option:
    """One way to run the frame: a schedule family, its GPUs, a link, in words (`settings`)
    and as overrides of the experiment."""

    family: str
    gpus: int
    link: str
    settings: str
    overrides: Mapping[str, Any]

    @property
    def label(self) -> str:
        if self.gpus == 1:
            return self.family
        return f"{self.family} x{self.gpus}" + (f", {self.settings}" if self.settings else "") + \
            f", {self.link}"


@dataclass
class Advice:
    """What the search found: every option's row (`table`), the confirmed ranking, the Pareto
    front, how long each level took and what the bound proves."""

    experiment: str
    options: list[Option]
    table: pd.DataFrame
    baseline: dict[str, float]
    analytic_bound: bool
    open: int
    timings: dict[str, float]
    counts: dict[str, int]
    notes: list[str] = field(default_factory=list)
    #: the overrides every option was given on top of its own (`advise --set`)
    base: dict[str, Any] = field(default_factory=dict)

    def overrides(self, index: int) -> dict[str, Any]:
        """All overrides of option `index`: the search's own and the option's."""
        return {**self.base, **self.options[index].overrides}

    @property
    def ranked(self) -> pd.DataFrame:
        """Confirmed options, best first: frame time, then latency, then GPUs."""
        ok = self.table[self.table["confirmed"]]
        return ok.sort_values(["frame_time_ms", "latency_ms", "gpus", "option"], kind="stable")

    @property
    def front(self) -> pd.DataFrame:
        return self.ranked[self.ranked["pareto"]]


# ----- the options ----------------------------------------------------------------------------
def options(exp: Experiment, max_gpus: int = 8, links: Sequence[Link] = LINKS) -> list[Option]:
    """Every option for the experiment's frame (see the module doc), the one-GPU baseline first."""
    raw = exp.raw.get("schedule", {})
    common = {k: raw[k] for k in COMMON_KEYS if k in raw}
    stereo = exp.schedule.name == "xr"
    scene_over = {"scene.passes": two_eye_passes(exp.raw["scene"]["passes"])} if stereo else {}
    out = [_baseline(exp, common)]
    for n in range(2, max_gpus + 1):
        for link in links:
            at = {**link.overrides, "profile.gpu_count": max(n, len(exp.profile.gpus))}
            out += _five_step(n, link, common, at, scene_over)
            out += _afr(exp, n, link, common, at, scene_over)
            if n == 2:
                out += _pipelining(exp, link, common, at, scene_over)
            if stereo and n in (2, 4):
                out += _xr(n, link, common, at)
    return out


def _baseline(exp: Experiment, common: dict[str, Any]) -> Option:
    raw = dict(exp.raw.get("schedule", {}))
    raw["gpus"] = 1
    family = "XR, both views on one GPU" if exp.schedule.name == "xr" else "one GPU"
    return Option(family, 1, "", "", {"schedule": raw})


def _five_step(n: int, link: Link, common: dict, at: dict, scene: dict) -> list[Option]:
    if link.nvlink:  # the five-step pipeline crosses through host memory only: no new option
        return []
    out = []
    for name, extra, family in (("sort_first", {"balance": True}, "sort-first balanced"),
                                ("sort_last", {}, "sort-last")):
        for host_copy in (True, False):
            sched = {"name": name, "gpus": n, **common, **extra, "host_copy": host_copy}
            out.append(Option(family, n, link.name, "host copy" if host_copy else "shared host memory",
                              {"schedule": sched, **at, **scene}))
    return out


def _afr(exp: Experiment, n: int, link: Link, common: dict, at: dict, scene: dict) -> list[Option]:
    sched: dict[str, Any] = {"name": "afr", "gpus": n, **common, **whole_cycles(common, n),
                             "frames_in_flight": max(n, int(common.get("frames_in_flight", 2)))}
    settings = f"{sched['frames_in_flight']} frames in flight"
    temporal = temporal_reads(exp.scene)
    if temporal:
        reader, producer = temporal[0]
        if scene:  # a stereo frame's two-eye scene: the left eye's copy carries it
            reader, producer = f"{reader}.left", f"{producer}.left"
        size = next(int(p.param("output_bytes")) for p in exp.scene.passes
                    if p.name == temporal[0][1])
        sched.update(temporal_pass=reader, history_bytes=size)
        settings += f", {reader} reads the previous frame"
    return [Option("AFR", n, link.name, settings, {"schedule": sched, **at, **scene})]


def whole_cycles(common: Mapping[str, Any], cycle: int) -> dict[str, int]:
    """Frames and warm-up for a schedule whose frames come in cycles of `cycle` (AFR: one per
    GPU): the warm-up covers two cycles and the measured periods are whole cycles, so that the
    mean period is the steady one (a part of a bursty cycle would bias it)."""
    warmup = max(int(common.get("warmup_frames", 5)), 2 * cycle)
    periods = max(int(common.get("frames", 60)) - warmup - 1, 4 * cycle)
    return {"warmup_frames": warmup, "frames": warmup + 1 + cycle * math.ceil(periods / cycle)}


def _pipelining(exp: Experiment, link: Link, common: dict, at: dict, scene: dict) -> list[Option]:
    passes = len(exp.scene.passes) * (2 if scene else 1)
    reads = any(p.reads for p in exp.scene.passes)
    out = []
    for split in range(1, passes + 1):
        for chunks in CHUNKS:
            sched = {"name": "pipelining", "gpus": 2, **common, "split_at": split, "chunks": chunks}
            if reads:
                sched["consumer_waits"] = "reads"
            settings = f"split after pass {split}" + (f", {chunks} chunks" if chunks > 1 else "")
            out.append(Option("pipelining", 2, link.name, settings, {"schedule": sched, **at, **scene}))
    return out


def _xr(n: int, link: Link, common: dict, at: dict) -> list[Option]:
    fif = min(int(common.get("frames_in_flight", 2)), 3)
    return [Option("XR", n, link.name, f"{scaling} scaling",
                   {"schedule": {"name": "xr", "gpus": n, **common, "frames_in_flight": fif,
                                 "scaling": scaling}, **at})
            for scaling in ("weak", "strong")]


def two_eye_passes(passes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A stereo frame's scene for schedules without views: every pass twice, the left eye's
    then the right eye's, each reading its own eye's passes."""
    out = []
    for eye in ("left", "right"):
        for p in passes:
            q = copy.deepcopy(p)
            q["name"] = f"{p['name']}.{eye}"
            if "reads" in q:
                q["reads"] = [f"{r}.{eye}" for r in q["reads"]]
            out.append(q)
    return out


# ----- evaluating them ------------------------------------------------------------------------
class _Loader:
    """One experiment file under many overrides: the file and each variant of its profile are
    read once (loading dominated the analytic level's time). The options' results are those of
    load_experiment; only the record of the what-ifs (`profile_overrides`) is left empty."""

    def __init__(self, path: str):
        self.path, self.raw = path, read_toml(Path(path))
        self.profile_file = load_experiment(path).profile.source
        self.profiles: dict[str, HardwareProfile] = {}

    def load(self, overrides: Mapping[str, Any]) -> Experiment:
        ours, theirs = split_profile(overrides)
        data = copy.deepcopy(self.raw)
        for key, value in ours.items():
            set_dotted(data, key, value, self.path)
        key = json.dumps(theirs, sort_keys=True, default=str)
        if key not in self.profiles:
            self.profiles[key] = load_profile(self.profile_file, theirs)
        return parse_experiment(data, self.path, base=Path(self.path).parent, profile=self.profiles[key])


@functools.lru_cache(maxsize=4)
def _loader(path: str, stamp: int) -> _Loader:
    """The loader of `path` as it is now (`stamp`: its modification time)."""
    return _Loader(path)


def evaluate(path: str, base: Mapping[str, Any], items: Sequence[tuple[int, Mapping[str, Any]]],
             fidelity: str, band: bool = False) -> list[dict[str, Any]]:
    """Frame time and latency of each (index, overrides) at `fidelity`, or the error a user
    would see for it (a schedule that cannot take the frame, memory that overflows)."""
    out = []
    for index, overrides in items:
        t0 = time.perf_counter()
        row: dict[str, Any] = {"option": index}
        try:
            exp = (_loader(path, Path(path).stat().st_mtime_ns).load({**base, **overrides})
                   if fidelity != "full" else load_experiment(path, {**base, **overrides}))
            result = simulate(exp, record_trace=False, fidelity=fidelity, band=band)
            s = result.summary
            row.update(frame_time_ms=s["frame_time_ms"], latency_ms=s["latency_ms"], error=None,
                       settled=s.get("settled", True))
            if band and "frame_time_ms_lo" in s:
                row.update({k: s[k] for k in ("frame_time_ms_lo", "frame_time_ms_hi",
                                              "latency_ms_lo", "latency_ms_hi")})
        except MgpusimError as exc:
            row.update(frame_time_ms=math.nan, latency_ms=math.nan, error=str(exc))
        row["wall_s"] = time.perf_counter() - t0
        out.append(row)
    return out


def _run(path: str, base: Mapping[str, Any], items: list[tuple[int, Mapping[str, Any]]],
         fidelity: str, workers: int, band: bool = False) -> list[dict[str, Any]]:
    """`evaluate` over the items, spread over `workers` processes (1: here)."""
    if workers <= 1 or len(items) < 2 * workers:
        return evaluate(path, base, items, fidelity, band)
    size = max(1, math.ceil(len(items) / (4 * workers)))
    chunks = [items[i:i + size] for i in range(0, len(items), size)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        parts = pool.map(evaluate, [path] * len(chunks), [base] * len(chunks), chunks,
                         [fidelity] * len(chunks), [band] * len(chunks))
        return [row for part in parts for row in part]


def search(path: str | Path, overrides: Mapping[str, Any] | None = None, *, max_gpus: int = 8,
           links: Sequence[Link] = LINKS, confirm: int = CONFIRM, workers: int | None = None,
           band: bool = True) -> Advice:
    """Search every option of the experiment at `path` (see the module doc)."""
    path, base = str(path), dict(overrides or {})
    exp = _start(path, base, max_gpus)
    workers = workers or os.cpu_count() or 1
    opts = options(exp, max_gpus, links)
    items = [(i, o.overrides) for i, o in enumerate(opts)]
    fast = "queues" if exp.schedule.refresh_hz else "analytic"  # the analytic level has no vsync
    t0 = time.perf_counter()
    table = _table(opts, pd.DataFrame(_run(path, base, items, fast, workers)).set_index("option"))
    t1 = time.perf_counter()
    full = _run(path, base, [items[i] for i in _to_confirm(table, confirm)], "full", workers, band)
    table = _merge_full(table, pd.DataFrame(full).set_index("option"))
    t2 = time.perf_counter()
    if not table["confirmed"].any():
        errors = table["error"].dropna()
        raise InputError("no option of this frame could run, not even on one GPU"
                         + (f" (the first error: {errors.iloc[0]})" if len(errors) else ""), file=path)
    bound = fast_level_is_bound(exp)
    baseline = cast(dict[str, float], table.loc[0, ["frame_time_ms", "latency_ms"]].to_dict())
    table["speedup"] = baseline["frame_time_ms"] / table["frame_time_ms"]
    notes = [] if bound else [f"the {fast} level is not a bound on this profile (its GPUs share the "
                              "CPU, which it leaves out): options outside the confirmed ones may do better"]
    notes += settle_notes(table)
    counts = {"options": len(opts), "failed": int(table["error"].notna().sum()),
              "confirmed": int(table["confirmed"].sum()), "workers": workers}
    return Advice(path, opts, table, baseline, bound, _open(table) if bound else -1,
                  {f"{fast}_s": t1 - t0, "full_s": t2 - t1}, counts, notes, base)


def settle_notes(table: pd.DataFrame) -> list[str]:
    """A note when confirmed options had not settled by the end of their run (`settled`,
    :mod:`mgpusim.results.settled`): their frame time or latency is not yet the steady state's,
    and the ranking may change with more frames."""
    confirmed = table[table["confirmed"]]
    if "settled" not in confirmed:
        return []
    short = confirmed[~confirmed["settled"].fillna(True).astype(bool)]
    if short.empty:
        return []
    names = ", ".join(str(label) for label in short["label"].head(3))
    return [f"{len(short)} of the {len(confirmed)} confirmed options had not settled by the end of "
            f"their run ({names}{', ...' if len(short) > 3 else ''}): their frame time or latency "
            "still moved over the last quarter of the frames, so their figures are not the steady "
            "state's; give the frame more frames (--set schedule.frames=N) before trusting the ranking"]


def _start(path: str, base: Mapping[str, Any], max_gpus: int) -> Experiment:
    """The experiment, checked: one GPU (the frame as captured), a GPU count in range."""
    exp = load_experiment(path, base)
    if exp.schedule.gpus != 1:
        raise InputError(f"advise starts from the frame on one GPU; this experiment runs "
                         f"{exp.schedule.name} on {exp.schedule.gpus} (set schedule.gpus = 1)",
                         file=path, field="schedule.gpus")
    if not 1 <= max_gpus <= 64:
        raise InputError(f"must be 1..64, got {max_gpus}", field="--max-gpus")
    return exp


def fast_level_is_bound(exp: Experiment) -> bool:
    """Whether the fast levels never make an option slower than `full` does: true unless the
    profile's GPUs share the host CPU (then they take the GPUs as independent devices, which is
    no bound: mgpusim.sim.analytic); every other approximation of theirs leaves out a slowdown."""
    return not exp.profile.host.gpus_share_cpu


def _table(opts: list[Option], first: pd.DataFrame) -> pd.DataFrame:
    meta = pd.DataFrame([{"option": i, "family": o.family, "gpus": o.gpus, "link": o.link,
                          "settings": o.settings, "label": o.label} for i, o in enumerate(opts)]).set_index("option")
    table = meta.join(first.rename(columns={"frame_time_ms": "fast_frame_time_ms",
                                            "latency_ms": "fast_latency_ms", "wall_s": "fast_wall_s"}))
    return table


def _to_confirm(table: pd.DataFrame, confirm: int) -> list[int]:
    """The baseline, the `confirm` best by the fast level's frame time, the best of each GPU
    count and of each schedule family, and the fast level's Pareto front of frame time and
    latency."""
    ok = table[table["error"].isna()]
    best = ok.sort_values(["fast_frame_time_ms", "fast_latency_ms", "gpus"], kind="stable")
    chosen = {0, *best.index[:confirm], *best.groupby("gpus").head(1).index,
              *best.groupby("family").head(1).index}
    chosen |= set(pareto(ok, ("fast_frame_time_ms", "fast_latency_ms")))
    return sorted(chosen)


def _merge_full(table: pd.DataFrame, full: pd.DataFrame) -> pd.DataFrame:
    table = table.copy()
    table["confirmed"] = table.index.isin(full.index) & full.reindex(table.index)["error"].isna()
    for col in full.columns:
        if col == "error":
            table["error"] = table["error"].where(table["error"].notna(), full["error"].reindex(table.index))
            continue
        table[col] = full[col].reindex(table.index)
    ok = table[table["confirmed"]]
    table["pareto"] = table.index.isin(pareto(ok, ("frame_time_ms", "latency_ms")))
    ranked = ok.sort_values(["frame_time_ms", "latency_ms", "gpus"], kind="stable").index
    table["rank"] = pd.Series(range(1, len(ranked) + 1), index=ranked).reindex(table.index).astype("Int64")
    return table


def _open(table: pd.DataFrame) -> int:
    """Options not confirmed whose fast frame time is below the best confirmed frame time:
    with the fast level an optimistic bound, only these could still beat the best."""
    best = table.loc[table["confirmed"], "frame_time_ms"].min()
    rest = table[~table["confirmed"] & table["error"].isna()]
    return int((rest["fast_frame_time_ms"] < best).sum())


def pareto(df: pd.DataFrame, cols: Iterable[str], tolerance: float = PARETO_TOLERANCE) -> list[int]:
    """The rows on the front, lower being better in every column: taken in order of the columns,
    a row joins unless one already on it is better in some column and no worse beyond
    `tolerance` (a share) in any. Why a tolerance: a latency 0.01 % shorter is no reason to
    keep an option 3x slower on the front, nor one of eight links that all give the same."""
    cols = list(cols)
    ordered = df.sort_values(cols, kind="stable")
    values = ordered[cols].to_numpy(dtype=float)
    kept: list[int] = []
    for i, row in enumerate(values):
        if not any((values[k] <= row * (1 + tolerance)).all() and (values[k] < row).any() for k in kept):
            kept.append(i)
    return sorted(ordered.index[k] for k in kept)


def option_command(experiment: str, overrides: Mapping[str, Any]) -> str:
    """The `mgpusim simulate` command that runs an option (overrides as --set TOML values)."""
    parts = [f"mgpusim simulate {experiment}"]
    for key, value in overrides.items():
        if key == "scene.passes":
            parts.append("--set 'scene.passes=<both eyes: see advice.json>'")
            continue
        parts.append(f"--set '{key}={toml_value(value)}'")
    return " ".join(parts)


def toml_value(value: Any) -> str:
    """A value as --set reads it (TOML: inline tables, lists, strings, numbers, booleans)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}={toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"not a TOML value: {value!r}")
