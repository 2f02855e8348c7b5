"""`mgpusim advise`: which multi-GPU schedule, how many GPUs and which link suit a frame.

The search (:func:`search`) builds every option from one experiment (usually an imported
frame): sort-first with balanced tiles and sort-last (each with a host copy between staging
buffers or one shared host allocation), alternate-frame rendering (carrying the frame's
temporal input, if it has one), frame pipelining over every contiguous split point with 1 to 8
chunks per copy, and XR stereo (2 or 4 GPUs, weak or strong scaling) where the frame has two
views; on 2 to 8 GPUs, over PCIe 3/4/5 x8/x16 and NVLink. Each option is a set of overrides of
the experiment (`mgpusim simulate EXPERIMENT --set ...` reproduces it). Every AFR option also
comes **evenly paced** (:func:`paced`): the engine holds each present to an even cadence
(`schedule.pace_us`), as engines do to keep AFR's GPUs from presenting in bursts.

**The ranking measure** is the 99th-percentile interval between presents (the mean interval
where that is larger: :data:`RANK_MEASURE`), from the simulated frames table, so that an option
that presents eight frames at once and then waits ranks by the wait, not by the mean. Options
whose measures are within :data:`TIE` of each other tie (the model's own timeline error,
docs/advise.md): a tie is ordered by latency (again within :data:`TIE`), then fewer GPUs, then
the cheaper link (the order of :data:`LINKS`).

Every option runs first at the `analytic` level (no event simulation; milliseconds each). The
best of them by the measure and by mean frame time, the best of each GPU count and of each
schedule, and those on the analytic Pareto front of the measure and latency are confirmed at
`full` fidelity; the ranking and the Pareto front are over the confirmed results. Where the
analytic level is an optimistic bound (every approximation it makes only speeds the model up:
docs/fidelity.md), an option whose analytic mean frame time is above the best confirmed measure
cannot beat it (its measure is never below its mean): :attr:`Advice.open` counts the options
below it that were not confirmed, so "the best" is proven when it is 0.

Pure: no file is written here (the command writes the report).
"""
from __future__ import annotations

import copy
import functools
import json
import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Hashable, Iterable, Mapping, Sequence, cast

import numpy as np
import pandas as pd

from mgpusim.advise.worker_set import Progress, Tally, Workers, workers_of
from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.model.overrides import set_dotted, split_profile
from mgpusim.model.profile import HardwareProfile, links_as_rates, load_profile, require_gpus
from mgpusim.model.scene import temporal_reads
from mgpusim.model.toml_checks import read_toml
from mgpusim.schedules.experiment import Experiment, load_experiment, parse_experiment
from mgpusim.sim.simulation import prepare_like, simulate, without_pace

#: Pipelining's chunks per copy, searched at every split point.
CHUNKS = tuple(range(1, 9))
#: Schedule keys every schedule takes (kept from the experiment when the schedule changes).
COMMON_KEYS = ("frames", "warmup_frames", "frames_in_flight", "refresh_hz", "cpu_frame_us")
#: Options confirmed at full fidelity by default, besides the analytic Pareto front.
CONFIRM = 24
#: Options whose ranking measures differ by less than this share tie. Why 1 %: it is the
#: model's own timeline error, the replay's median target, which every held-out schedule's
#: replay meets on the NVIDIA runs of the native runner core (docs/replay.md). The options of
#: one frame share its pass costs, so what sets them apart is their timelines, and a difference
#: below the timeline's own error is not one the model can tell.
TIE = 0.01
#: Differences smaller than this share do not keep an option on the Pareto front (a tie).
PARETO_TOLERANCE = TIE
#: The percentile of the steady intervals between presents that ranks the options.
PERCENTILE = 99
#: What the options are ranked by, in words (the report and docs say it).
RANK_MEASURE = (f"the {PERCENTILE}th-percentile interval between presents (the mean interval "
                "where that is larger)")
#: Even pacing's cadence, as shares above the unpaced option's mean interval: the one that ranks
#: best is kept (at the mean itself the GPUs have no slack, and the cadence can slip).
PACE_MARGINS = (0.0, 0.01, 0.02, 0.05)
#: The family of evenly paced AFR options.
PACED = "AFR, even pacing"
#: The most passes a frame may have (a stereo frame's passes counted for both eyes): frame
#: pipelining tries every split point with every chunk count on every link, so its options
#: grow with the passes, and each costs more to model the more passes it has (one program and
#: one model per split point and chunk count, shared by the links). On the shared 2-core
#: machine with 2 workers (benchmarks/advise_passes.py, other jobs running): 20 passes take
#: 25-32 s, 64 passes about 100 s; 200 passes (12,800 pipelining options) would take over
#: 10 minutes, so such a frame is refused before any work rather than left to run.
MAX_PASSES = 64


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
#: profile's own PCIe link. In order of cost, cheapest first (an older PCIe generation, then
#: fewer lanes, then NVLink: a bridge, then NVSwitch), which orders options that tie.
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
    #: an evenly paced AFR option: the index of the same option unpaced
    paced_from: int | None = None
    #: what the label adds to the settings that does not tell options apart (a cadence)
    detail: str = ""

    @property
    def label(self) -> str:
        if self.gpus == 1:
            return self.family
        words = ", ".join(w for w in (self.settings, self.detail) if w)
        return f"{self.family} x{self.gpus}" + (f", {words}" if words else "") + f", {self.link}"


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
    #: the links' places in order of cost, cheapest first (ties go to the cheaper)
    link_order: dict[str, int] = field(default_factory=dict)
    #: the passes' pixel shares, where each came from, and the answer with the assumed ones
    #: moved (:func:`mgpusim.advise.assumptions.check_shares`); empty where not checked
    assumptions: dict[str, Any] = field(default_factory=dict)

    def overrides(self, index: int) -> dict[str, Any]:
        """All overrides of option `index`: the search's own and the option's."""
        return {**self.base, **self.options[index].overrides}

    @property
    def ranked(self) -> pd.DataFrame:
        """Confirmed options, best first (`rank`, see the module doc)."""
        ok = self.table[self.table["confirmed"]]
        return ok.loc[ok["order"].sort_values(kind="stable").index]

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
        self.file = str(Path(path))  # (as load_experiment names it)
        self.profile_file = load_experiment(path).profile.source
        self.profiles: dict[str, HardwareProfile] = {}
        #: the options loaded last, by their overrides but the profile's and the cadence, each
        #: with those overrides but the profile's as text (see `load_like`)
        self.last: dict[str, list[tuple[str, Experiment]]] = {}

    def load(self, overrides: Mapping[str, Any]) -> Experiment:
        ours, theirs = split_profile(overrides)
        data = copy.deepcopy(self.raw)
        for key, value in ours.items():
            set_dotted(data, key, value, self.path)
        return parse_experiment(data, self.path, base=Path(self.path).parent, profile=self._profile(theirs))

    def load_as_given(self, overrides: Mapping[str, Any]) -> Experiment:
        """`load_experiment(path, overrides)`, its what-ifs recorded (so that `simulate` refuses
        a ``profile.`` override it never reads), on the profile loaded once for those
        overrides. Why: `simulate` watches what is read of each profile object through a copy
        of it made once per object (:mod:`mgpusim.model.profile_reads`), which a profile loaded
        for every option would make again each time. (An override of the experiment's
        `profile` itself is loaded by `load_experiment`.)"""
        ours, theirs = split_profile(overrides)
        if "profile" in ours:
            return load_experiment(self.path, overrides)
        exp = self.load(overrides)
        return replace(exp, file=self.file, profile_overrides=MappingProxyType(
            {f"profile.{k}": v for k, v in theirs.items()}))

    def load_like(self, overrides: Mapping[str, Any], fidelity: str) -> Experiment:
        """`load(overrides)`, sharing the program and model of an option loaded before with the
        same overrides but for the profile's (another link) and the cadence (an evenly paced
        AFR option's `pace_us`): :func:`prepare_like`. Why: the options of one schedule over
        eight links, and each AFR option at four cadences, would otherwise build one program
        and model each. The options of the last such overrides are kept (one per program:
        PCIe, NVLink)."""
        ours, theirs = split_profile(overrides)
        text = json.dumps(ours, sort_keys=True, default=str)
        family = json.dumps(without_pace(ours), sort_keys=True, default=str)
        sources = self.last.get(family)
        if sources is None:
            exp = self.load(overrides)
            self.last = {family: [(text, exp)]}
            return exp
        profile = self._profile(theirs)
        same = [source for at, source in sources if at == text]
        for source in same:
            if profile is source.profile:
                return source
        if same:
            require_gpus(profile, same[0].schedule.gpus, self.path)
            exp = replace(same[0], profile=profile)
        else:  # another cadence
            exp = self.load(overrides)
        if not any(prepare_like(exp, source, fidelity) for _, source in sources):
            sources.append((text, exp))
        return exp

    def _profile(self, theirs: Mapping[str, Any]) -> HardwareProfile:
        """The profile under the overrides `theirs` (loaded once)."""
        key = json.dumps(theirs, sort_keys=True, default=str)
        if key not in self.profiles:
            self.profiles[key] = load_profile(self.profile_file, theirs)
        return self.profiles[key]


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
            loader = _loader(path, Path(path).stat().st_mtime_ns)
            exp = (loader.load_like({**base, **overrides}, fidelity) if fidelity != "full"
                   else loader.load_as_given({**base, **overrides}))
            result = simulate(exp, record_trace=False, fidelity=fidelity, band=band)
            s = result.summary
            row.update(frame_time_ms=s["frame_time_ms"], latency_ms=s["latency_ms"], error=None,
                       settled=s.get("settled", True), **_intervals(result, s))
            if band and "frame_time_ms_lo" in s:
                row.update({k: s[k] for k in ("frame_time_ms_lo", "frame_time_ms_hi",
                                              "latency_ms_lo", "latency_ms_hi")})
        except MgpusimError as exc:
            row.update(frame_time_ms=math.nan, latency_ms=math.nan, error=str(exc),
                       interval_p99_ms=math.nan, interval_max_ms=math.nan)
        row["wall_s"] = time.perf_counter() - t0
        out.append(row)
    return out


def _intervals(result: Any, summary: Mapping[str, Any]) -> dict[str, float]:
    """:func:`intervals` of a simulated result, from its presents array where it has one (the
    frames table costs more to build than a short analytic run)."""
    if result.frame_arrays is None:
        return intervals(result.frames, summary)
    present = np.asarray(result.frame_arrays[1], dtype=np.int64)
    return steady_intervals(present[max(int(summary["warmup_frames"]), 0):], summary)


def intervals(frames: pd.DataFrame, summary: Mapping[str, Any]) -> dict[str, float]:
    """The steady intervals between presents (those of the frames after the warm-up, as the
    summary's mean): their :data:`PERCENTILE`th percentile (numpy's linear interpolation) and
    the worst, in ms."""
    presents = frames.loc[frames["frame"] >= summary["warmup_frames"], "present_ns"].to_numpy(np.int64)
    return steady_intervals(presents, summary)


def steady_intervals(presents: np.ndarray, summary: Mapping[str, Any]) -> dict[str, float]:
    """:func:`intervals` of the steady frames' presents (ns, in frame order)."""
    periods = np.diff(presents)
    if not len(periods):  # one steady frame: its period is the summary's
        return {"interval_p99_ms": summary["frame_time_ms"], "interval_max_ms": summary["frame_time_ms"]}
    return {"interval_p99_ms": float(np.percentile(periods, PERCENTILE)) / 1e6,
            "interval_max_ms": float(periods.max()) / 1e6}


#: The most options one task of a worker evaluates: small enough that progress moves often
#: on a long search, large enough that handing tasks out costs nothing next to running them.
TASK_OPTIONS = 32


class Batch:
    """Options handed to the workers in tasks of up to :data:`TASK_OPTIONS`; :meth:`rows`
    waits for them. At the fast levels the options of one schedule over every link are handed
    in side by side (they share a program and a model: `load_like`). Options that are one run
    of the model (:class:`SameRuns`) are handed in once, and each gets that run's row."""

    def __init__(self, workers: Workers, path: str, base: Mapping[str, Any],
                 items: Sequence[tuple[int, Mapping[str, Any]]], fidelity: str, band: bool = False,
                 tally: Tally | None = None):
        self.items = items
        #: for each item, the place of the one that runs for it among `runs`
        self.run_of, runs = _one_per_run(path, base, items)
        stands = np.bincount(self.run_of, minlength=len(runs)) if runs else np.zeros(0, dtype=int)
        self.order = (sorted(range(len(runs)), key=lambda k: _without_profile(runs[k][1]))
                      if fidelity != "full" else list(range(len(runs))))
        self.tally = tally if tally is not None else Tally(None, "")
        size = max(1, min(TASK_OPTIONS, math.ceil(len(runs) / (4 * workers.count))))
        self.tasks = []
        for start in range(0, len(self.order), size):
            chunk = self.order[start:start + size]
            self.tasks.append(workers.submit(evaluate, path, dict(base), [runs[k] for k in chunk], fidelity, band))
            self.tally.add(self.tasks[-1], int(stands[chunk].sum()))

    def rows(self) -> list[dict[str, Any]]:
        """`evaluate`'s rows, in the order of the items handed in."""
        self.tally.wait(self.tasks)
        back: list[dict[str, Any]] = [{}] * len(self.order)
        for k, row in zip(self.order, (row for task in self.tasks for row in task.result())):
            back[k] = row
        return [back[run] if back[run]["option"] == index else {**back[run], "option": index}
                for (index, _), run in zip(self.items, self.run_of)]


def _one_per_run(path: str, base: Mapping[str, Any], items: Sequence[tuple[int, Mapping[str, Any]]]
                 ) -> tuple[list[int], list[tuple[int, Mapping[str, Any]]]]:
    """For each item the place of the item that runs for it, and those items (the first of
    each run of the model, in order)."""
    same = _same_runs(path, Path(path).stat().st_mtime_ns)
    place: dict[Hashable, int] = {}
    runs: list[tuple[int, Mapping[str, Any]]] = []
    run_of = []
    for item in items:
        key = same.key({**base, **item[1]})
        if key not in place:
            place[key] = len(runs)
            runs.append(item)
        run_of.append(place[key])
    return run_of, runs


class SameRuns:
    """Which options are one run of the model: the same overrides but the profile's, on
    profiles that differ in nothing the model reads. Why: links of one rate and latency are
    one run (PCIe 3.0 x16 and 4.0 x8 both carry 0.985 x 16 GB/s; so do 4.0 x16 and 5.0 x8,
    :func:`mgpusim.model.profile.links_as_rates`), and a search over links would run each
    twice: a quarter of the options of every schedule searched over all eight links."""

    def __init__(self, path: str):
        self.profile_file = load_experiment(path).profile.source
        #: profile overrides (as text) -> the place of the profile they give among `seen`
        self.place: dict[str, int] = {}
        self.seen: list[HardwareProfile] = []

    def key(self, overrides: Mapping[str, Any]) -> tuple[str, int]:
        """Equal for options that are one run of the model (see the class doc)."""
        ours, theirs = split_profile(overrides)
        text = json.dumps(theirs, sort_keys=True, default=str)
        if text not in self.place:
            self.place[text] = self._place(theirs)
        return json.dumps(ours, sort_keys=True, default=str), self.place[text]

    def _place(self, theirs: Mapping[str, Any]) -> int:
        """The place of the profile `theirs` gives among those seen (a new one is added); a
        profile that fails to load is one of its own (its options report the error)."""
        try:
            profile = links_as_rates(load_profile(self.profile_file, theirs))
        except MgpusimError:
            return -1 - len(self.place)
        for k, seen in enumerate(self.seen):
            if seen == profile:
                return k
        self.seen.append(profile)
        return len(self.seen) - 1


@functools.lru_cache(maxsize=4)
def _same_runs(path: str, stamp: int) -> SameRuns:
    """The :class:`SameRuns` of `path` as it is now (`stamp`: its modification time)."""
    return SameRuns(path)


def run_options(path: str, base: Mapping[str, Any], items: list[tuple[int, Mapping[str, Any]]],
                fidelity: str, workers: int | Workers, band: bool = False, progress: Progress | None = None,
                stage: str = "") -> list[dict[str, Any]]:
    """`evaluate` over the items, spread over the workers (`workers` processes started for
    them, where there are enough items to share: else here), in the items' order;
    `progress(stage, done, total)` as tasks end."""
    if not isinstance(workers, Workers) and len(items) < 2 * workers:
        workers = 1
    with workers_of(workers) as pool:
        return Batch(pool, path, base, items, fidelity, band, Tally(progress, stage, len(items))).rows()


def _without_profile(overrides: Mapping[str, Any]) -> str:
    """An option's overrides but the profile's, as text: the options of one schedule on every link."""
    return json.dumps(split_profile(overrides)[0], sort_keys=True, default=str)


def search(path: str | Path, overrides: Mapping[str, Any] | None = None, *, max_gpus: int = 8,
           links: Sequence[Link] = LINKS, confirm: int = CONFIRM, workers: int | Workers | None = None,
           band: bool = True, progress: Progress | None = None) -> Advice:
    """Search every option of the experiment at `path` (see the module doc). How the answer
    moves if the passes' assumed pixel shares are off is a second step on the result
    (:func:`mgpusim.advise.assumptions.check_shares`). `workers`: a count of processes (default:
    one per CPU) or a command's :class:`Workers`, left running for its next stages.
    `progress(stage, done, total)`: the options evaluated so far in each stage of the search."""
    path, base = str(path), dict(overrides or {})
    exp = check_frame(path, base, max_gpus)
    with workers_of(workers or os.cpu_count() or 1) as pool:
        return _search(path, base, exp, options(exp, max_gpus, links), links, confirm, pool, band, progress)


def _search(path: str, base: dict[str, Any], exp: Experiment, opts: list[Option], links: Sequence[Link],
            confirm: int, workers: Workers, band: bool, progress: Progress | None) -> Advice:
    fast = "queues" if exp.schedule.refresh_hz else "analytic"  # the analytic level has no vsync
    t0 = time.perf_counter()
    opts, first = _fast_level(path, base, opts, fast, workers, progress)
    table = _table(opts, first)
    t1 = time.perf_counter()
    chosen = _to_confirm(table, confirm)
    # a paced option's cadence comes from its unpaced option's mean at the same level
    chosen |= {u for i in chosen if (u := opts[i].paced_from) is not None}
    opts, full, refast = _full_level(path, base, opts, chosen, workers, band, progress)
    if refast:  # the analytic row of a paced option at the cadence it kept
        again = Batch(workers, path, base, [(i, opts[i].overrides) for i in refast], fast,
                      tally=Tally(progress, f"{fast} level, paced again", len(refast))).rows()
        table = _refresh_fast(table, by_option(again))
    link_order = {link.name: k for k, link in enumerate(links)}
    table = _merge_full(table, full, link_order)
    table["label"] = [opts[i].label for i in table.index]
    t2 = time.perf_counter()
    if not table["confirmed"].any():
        errors = table["error"].dropna()
        raise InputError("no option of this frame could run, not even on one GPU"
                         + (f" (the first error: {errors.iloc[0]})" if len(errors) else ""), file=path)
    bound = fast_level_is_bound(exp)
    baseline = cast(dict[str, float], table.loc[0, ["frame_time_ms", "latency_ms", "interval_p99_ms",
                                                    "interval_max_ms", "rank_ms"]].to_dict())
    table["speedup"] = baseline["rank_ms"] / table["rank_ms"]
    notes = [] if bound else [f"the {fast} level is not a bound on this profile (its GPUs share the "
                              "CPU, which it leaves out): options outside the confirmed ones may do better"]
    notes += settle_notes(table)
    counts = {"options": len(opts), "failed": int(table["error"].notna().sum()),
              "confirmed": int(table["confirmed"].sum()), "workers": workers.count,
              "paced": sum(o.paced_from is not None for o in opts)}
    return Advice(path, opts, table, baseline, bound, _open(table) if bound else -1,
                  {f"{fast}_s": t1 - t0, "full_s": t2 - t1}, counts, notes, base, link_order)


def by_option(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """`evaluate`'s rows as a table by option index."""
    return pd.DataFrame(rows).set_index("option")


# ----- even pacing ----------------------------------------------------------------------------
def paced(option: Option, source: int, pace_us: float) -> Option:
    """`option` (AFR) with its presents held to an even cadence of `pace_us`."""
    sched = {**option.overrides["schedule"], "pace_us": pace_us}
    return Option(PACED, option.gpus, option.link, option.settings, {**option.overrides, "schedule": sched},
                  paced_from=source, detail=f"presents every {pace_us / 1000:.3f} ms")


def cadences(mean_ms: float) -> list[float]:
    """The cadences tried for an AFR option whose presents come every `mean_ms` on average
    (:data:`PACE_MARGINS` above it), in us, whole ns."""
    return [math.ceil(mean_ms * 1e6 * (1 + m)) / 1000 for m in PACE_MARGINS]


class Cadences:
    """The cadences of :func:`cadences` tried for each unpaced AFR option (index -> its mean
    interval at `fidelity`), handed to the workers; :meth:`best` waits for them. `stage`:
    the progress callback and the stage it reports as."""

    def __init__(self, workers: Workers, path: str, base: Mapping[str, Any], opts: Sequence[Option],
                 means: Mapping[int, float], fidelity: str, band: bool = False,
                 stage: tuple[Progress | None, str] = (None, "")):
        self.tried = [(u, pace) for u, mean in means.items() for pace in cadences(mean)]
        items = [(k, paced(opts[u], u, pace).overrides) for k, (u, pace) in enumerate(self.tried)]
        self.batch = Batch(workers, path, base, items, fidelity, band, Tally(*stage, len(items)))

    def best(self) -> dict[int, tuple[float, dict[str, Any]]]:
        """For each option, the cadence whose paced run ranks best (measure, then latency, then
        the slower cadence is not preferred), with that run's row."""
        out: dict[int, tuple[float, dict[str, Any]]] = {}
        for (u, pace), row in zip(self.tried, sorted(self.batch.rows(), key=lambda r: r["option"])):
            if row["error"] is not None:
                out.setdefault(u, (pace, row))
                continue
            key = (rank_of(row), row["latency_ms"], pace)
            held = out.get(u)
            if held is None or held[1]["error"] is not None or key < (rank_of(held[1]), held[1]["latency_ms"], held[0]):
                out[u] = (pace, row)
        return out


def rank_of(row: Mapping[str, Any]) -> float:
    """The ranking measure of a result (:data:`RANK_MEASURE`)."""
    return max(row["frame_time_ms"], row["interval_p99_ms"])


def cell(df: pd.DataFrame, index: int, col: str) -> Any:
    """One value of a table of options (by option index and column)."""
    value: Any = df.at[index, col]
    return value


def ran(df: pd.DataFrame, index: int) -> bool:
    """Whether option `index` is in a table of results and ran without an error."""
    return index in df.index and not isinstance(cell(df, index, "error"), str)


def paced_sources(opts: Sequence[Option], picks: Iterable[int]) -> dict[int, int]:
    """The paced options among `picks` by the unpaced option each comes from."""
    return {u: p for p in picks if (u := opts[p].paced_from) is not None}


def _paces(option: Option) -> bool:
    """Whether the option is an unpaced AFR option on several GPUs (one that is paced too)."""
    return option.family == "AFR" and option.gpus > 1 and option.paced_from is None


def _pace_sources(opts: Sequence[Option], rows: pd.DataFrame) -> dict[int, float]:
    """Unpaced AFR options on several GPUs that ran, with their mean intervals."""
    return {i: float(cell(rows, i, "frame_time_ms")) for i, o in enumerate(opts) if _paces(o) and ran(rows, i)}


def _fast_level(path: str, base: Mapping[str, Any], opts: list[Option], fidelity: str, workers: Workers,
                progress: Progress | None = None) -> tuple[list[Option], pd.DataFrame]:
    """Every option at the fast level, and every AFR option on several GPUs again, evenly paced
    at its best cadence. The AFR options are handed in first, so that their paced runs are
    queued while the rest still run."""
    items = list(enumerate(o.overrides for o in opts))
    tally = Tally(progress, f"{fidelity} level", len(items))
    afr = Batch(workers, path, base, [(i, o) for i, o in items if _paces(opts[i])], fidelity, tally=tally)
    rest = Batch(workers, path, base, [(i, o) for i, o in items if not _paces(opts[i])], fidelity, tally=tally)
    afr_rows = afr.rows()
    means = _pace_sources(opts, by_option(afr_rows)) if afr_rows else {}
    pacing = Cadences(workers, path, base, opts, means, fidelity, stage=(progress, f"even pacing, {fidelity} level"))
    rows = by_option(sorted(afr_rows + rest.rows(), key=lambda r: r["option"]))
    opts = list(opts)
    extra = []
    for u, (pace, row) in pacing.best().items():
        extra.append({**row, "option": len(opts)})
        opts.append(paced(opts[u], u, pace))
    if not extra:
        return opts, rows
    return opts, pd.concat([rows, by_option(extra)])


def _full_level(path: str, base: Mapping[str, Any], opts: list[Option], chosen: set[int], workers: Workers,
                band: bool, progress: Progress | None = None) -> tuple[list[Option], pd.DataFrame, list[int]]:
    """The chosen options at full fidelity, a paced one at its cadence found again from its
    unpaced option's full-fidelity mean (the fast level's may be shorter); those whose cadence
    moved, to be run again at the fast level. The unpaced options of paced ones are handed in
    first, so that the cadences are queued while the rest still run."""
    plain = [i for i in sorted(chosen) if opts[i].paced_from is None]
    sources = paced_sources(opts, sorted(chosen - set(plain)))
    tally = Tally(progress, "full fidelity", len(plain))
    first = Batch(workers, path, base, [(i, opts[i].overrides) for i in plain if i in sources], "full", band, tally)
    rest = Batch(workers, path, base, [(i, opts[i].overrides) for i in plain if i not in sources], "full", band,
                 tally)
    ran_first = {row["option"]: row for row in first.rows()}
    means = {u: float(ran_first[u]["frame_time_ms"]) for u in sources
             if u in ran_first and ran_first[u]["error"] is None}
    pacing = Cadences(workers, path, base, opts, means, "full", band, (progress, "even pacing, full fidelity"))
    full = by_option(sorted([*ran_first.values(), *rest.rows()], key=lambda r: r["option"]))
    found = pacing.best()
    opts, moved = list(opts), []
    rows: list[dict[str, Any]] = []
    for u, p in sources.items():
        if u not in found:  # its unpaced option failed at full fidelity: so does it
            rows.append({"option": p, "frame_time_ms": math.nan, "latency_ms": math.nan,
                         "interval_p99_ms": math.nan, "interval_max_ms": math.nan,
                         "error": cell(full, u, "error") if u in full.index else "not run"})
            continue
        pace, row = found[u]
        if pace != opts[p].overrides["schedule"]["pace_us"]:
            opts[p] = paced(opts[u], u, pace)
            moved.append(p)
        rows.append({**row, "option": p})
    if not rows:
        return opts, full, moved
    return opts, pd.concat([full, by_option(rows)]), moved


def _refresh_fast(table: pd.DataFrame, rows: pd.DataFrame) -> pd.DataFrame:
    """The table with the fast level's columns of `rows`' options replaced."""
    table = table.copy()
    fast = _fast_columns(rows)
    for col in fast.columns:
        if col in table.columns:
            table.loc[fast.index, col] = fast[col]
    return table


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


def check_frame(path: str | Path, base: Mapping[str, Any] | None = None, max_gpus: int = 8) -> Experiment:
    """The experiment, checked before any work: one GPU (the frame as captured), a GPU count in
    range, at most :data:`MAX_PASSES` passes where several GPUs are searched. A command calls
    it before it touches its output folder, so that bad input leaves that folder as it was."""
    path = str(path)
    exp = load_experiment(path, base or {})
    if exp.schedule.gpus != 1:
        raise InputError(f"advise starts from the frame on one GPU; this experiment runs "
                         f"{exp.schedule.name} on {exp.schedule.gpus} (set schedule.gpus = 1)",
                         file=path, field="schedule.gpus")
    if not 1 <= max_gpus <= 64:
        raise InputError(f"must be 1..64, got {max_gpus}", field="--max-gpus")
    passes = len(exp.scene.passes) * (2 if exp.schedule.name == "xr" else 1)
    if passes > MAX_PASSES and max_gpus > 1:  # (on one GPU only the frame itself runs)
        raise InputError(f"advise takes frames of up to {MAX_PASSES} passes, this one has {passes}: "
                         f"frame pipelining alone would be {passes * len(CHUNKS) * len(LINKS):,} options "
                         f"(every split point x {len(CHUNKS)} chunk counts x {len(LINKS)} links), each "
                         "slower to model the more passes there are (on 2 cores 64 passes take about "
                         "100 s, 200 would take over 10 minutes); merge small passes in the capture "
                         "before `mgpusim frame import`",
                         file=path, field="scene.passes")
    return exp


def fast_level_is_bound(exp: Experiment) -> bool:
    """Whether the fast levels never make an option slower than `full` does: true unless the
    profile's GPUs share the host CPU (then they take the GPUs as independent devices, which is
    no bound: mgpusim.sim.analytic); every other approximation of theirs leaves out a slowdown."""
    return not exp.profile.host.gpus_share_cpu


def _fast_columns(first: pd.DataFrame) -> pd.DataFrame:
    out = first.rename(columns={"frame_time_ms": "fast_frame_time_ms", "latency_ms": "fast_latency_ms",
                                "interval_p99_ms": "fast_interval_p99_ms",
                                "interval_max_ms": "fast_interval_max_ms", "wall_s": "fast_wall_s"})
    out["fast_rank_ms"] = out[["fast_frame_time_ms", "fast_interval_p99_ms"]].max(axis=1, skipna=False)
    return out


def _table(opts: list[Option], first: pd.DataFrame) -> pd.DataFrame:
    meta = pd.DataFrame([{"option": i, "family": o.family, "gpus": o.gpus, "link": o.link,
                          "settings": o.settings, "label": o.label,
                          "paced_from": o.paced_from if o.paced_from is not None else pd.NA}
                         for i, o in enumerate(opts)]).set_index("option")
    meta["paced_from"] = meta["paced_from"].astype("Int64")
    return meta.join(_fast_columns(first))


def _to_confirm(table: pd.DataFrame, confirm: int) -> set[int]:
    """The baseline, the `confirm` best by the fast level's ranking measure, the best of each
    GPU count and of each schedule family, up to `confirm` whose fast mean frame time is below
    the best fast measure (with the fast level a bound, only they could beat it at full
    fidelity), and the fast level's Pareto front of the measure and latency."""
    ok = table[table["error"].isna()]
    best = ok.sort_values(["fast_rank_ms", "fast_latency_ms", "gpus"], kind="stable")
    chosen = {0, *best.index[:confirm], *best.groupby("gpus").head(1).index,
              *best.groupby("family").head(1).index}
    if len(best):
        below = ok[ok["fast_frame_time_ms"] < best["fast_rank_ms"].iloc[0]]
        chosen |= set(below.sort_values(["fast_frame_time_ms", "gpus"], kind="stable").index[:confirm])
    chosen |= set(pareto(ok, ("fast_rank_ms", "fast_latency_ms")))
    return {int(i) for i in chosen}


def _merge_full(table: pd.DataFrame, full: pd.DataFrame, link_order: Mapping[str, int]) -> pd.DataFrame:
    table = table.copy()
    table["confirmed"] = table.index.isin(full.index) & full.reindex(table.index)["error"].isna()
    for col in full.columns:
        if col == "error":
            table["error"] = table["error"].where(table["error"].notna(), full["error"].reindex(table.index))
            continue
        table[col] = full[col].reindex(table.index)
    table["rank_ms"] = table[["frame_time_ms", "interval_p99_ms"]].max(axis=1, skipna=False)
    ok = table[table["confirmed"]]
    table["pareto"] = table.index.isin(pareto(ok, ("rank_ms", "latency_ms")))
    order = ranking(ok, link_order)
    for col in order.columns:
        table[col] = order[col].reindex(table.index)
    for col in ("order", "rank"):
        table[col] = table[col].astype("Int64")
    # a row of tied options is on the front if one of them is (the cheapest stands for it)
    on_front = table.loc[table["pareto"], "rank"].dropna().unique()
    table["pareto"] = table["rank"].isin(on_front).astype(bool)
    return table


def ranking(ok: pd.DataFrame, link_order: Mapping[str, int], tie: float = TIE) -> pd.DataFrame:
    """The confirmed options in order (`order`, 1 = best) and collapsed (`rank`): options whose
    measures (`rank_ms`) are within `tie` of the first of their group tie, and a tie is ordered
    by latency (groups within `tie` again), then GPUs, then the cheaper link (`link_order`: a
    link's place, cheapest first). Options of one tie and latency group that differ only in
    their link are one row of the table: they share its rank, its first (cheapest) option
    stands for them and `also_on` names the other links, cheapest first."""
    cost = ok["link"].map(lambda name: link_order.get(name, len(link_order)) if name else -1)
    df = ok.assign(_cost=cost)
    ordered: list[tuple[int, int, int]] = []  # (option, tie group, latency group)
    groups = 0
    for group in _ties(df.sort_values(["rank_ms", "latency_ms", "gpus", "_cost"], kind="stable"), "rank_ms", tie):
        for sub in _ties(group.sort_values(["latency_ms", "gpus", "_cost", "rank_ms"], kind="stable"),
                         "latency_ms", tie):
            groups += 1
            ordered += [(int(i), groups, 0) for i in
                        sub.sort_values(["gpus", "_cost", "rank_ms", "latency_ms"], kind="stable").index]
    rank: dict[int, int] = {}
    rows: dict[tuple, int] = {}  # (group, family, gpus, settings) -> the option that stands for it
    also: dict[int, list[str]] = {}
    heads: list[int] = []
    for i, g, _ in ordered:
        key = (g, cell(ok, i, "family"), int(cell(ok, i, "gpus")), cell(ok, i, "settings"))
        head = rows.setdefault(key, i)
        heads.append(head)
        if head == i:
            rank[i] = len(rows)
            also[i] = []
        else:
            rank[i] = rank[head]
            also[head].append(str(cell(ok, i, "link")))
    index = [i for i, _, _ in ordered]
    return pd.DataFrame({"order": range(1, len(index) + 1), "rank": [rank[i] for i in index],
                         "also_on": [", ".join(also[i]) if i in also else None for i in index],
                         "stands_for": heads},
                        index=pd.Index(index, name="option"))


def _ties(df: pd.DataFrame, col: str, tie: float) -> Iterable[pd.DataFrame]:
    """Consecutive groups of rows sorted by `col`: each from its first row to the last within
    `tie` (a share) of it."""
    values = df[col].to_numpy(dtype=float)
    start = 0
    while start < len(values):
        end = start + 1
        while end < len(values) and values[end] <= values[start] * (1 + tie):
            end += 1
        yield df.iloc[start:end]
        start = end


def _open(table: pd.DataFrame) -> int:
    """Options not confirmed whose fast mean frame time is below the best confirmed measure:
    with the fast level an optimistic bound (on the mean, which no measure is below), only these
    could still beat the best."""
    best = table.loc[table["confirmed"], "rank_ms"].min()
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
