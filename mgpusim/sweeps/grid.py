"""Sweeps: one experiment run over the product of a grid of overrides.

``sweep("experiments/sort_first_tc1.toml", {"schedule.gpus": [1, 2, 3], "scene.width": [1024, 1920]})``
runs six points and returns one row per point: the point's keys, every summary field
(flattened to dotted columns: ``utilization.gpu0.graphics``) and an ``error`` column, so that
a point whose override is invalid is a row, not the end of the sweep.

The experiment file is parsed once and each point's overrides set in memory
(:mod:`mgpusim.sweeps.loader`). At the analytic level every grid runs as numpy lanes
(:mod:`mgpusim.sweeps.lanes`: pass-cost keys as lanes, every other key as groups of one
structure run together, saved one batch at a time); points lanes cannot express, and every
point at the event-model levels, run one by one, in local processes (a few points handed to a
worker at once) or on a Dask cluster. Given an output folder, finished points are saved a batch
file at a time (see :mod:`mgpusim.sweeps.store`: a batch of lanes, or the points run one by one
in about the last half second) and a sweep started again over the same folder skips them: a
sweep killed at any moment loses at most the points of the batch it was running (half a
second of points run one by one) and recomputes no saved point. The table is written once, at
the end. A point is known by a hash of the bytes of every file its load reads (the experiment
and the profile files it names, :func:`input_files`), the package version, the base overrides,
its keys and the fidelity: editing the experiment or a profile it reads, or upgrading mgpusim,
makes new points that run again (the old ones stay on disk unused, never mixed into the table).
"""
from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import math
import os
import re
import time
import warnings
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from mgpusim import __version__
from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.model.limits import MAX_SWEEP_POINTS, MAX_SWEEP_WORKERS, WHY_SWEEP
from mgpusim.model.toml_checks import did_you_mean
from mgpusim.schedules.experiment import parse_value
from mgpusim.sim.effects import FIDELITIES
from mgpusim.sim.simulation import simulate
from mgpusim.sweeps.lanes import LaneRun, flatten
from mgpusim.sweeps.loader import fresh as fresh_loader
from mgpusim.sweeps.loader import shared as loader
from mgpusim.sweeps.pool import fewer_collections, local_pool

#: How long to try reaching a Dask scheduler before giving up.
DASK_CONNECT_TIMEOUT = "10s"

#: What a point's record holds besides its summary.
META_COLUMNS = ("point", "error", "wall_s")
#: Points run one by one are saved together, one batch file about this often (seconds): a
#: sweep killed at any moment loses at most the points it finished since. (The environment's
#: MGPUSIM_SWEEP_SAVE_S, when set, is used instead: 0 saves every point as it finishes.)
SAVE_EVERY_S = 0.5
#: Most points a pool worker is handed at once (fewer for short sweeps: every worker busy).
POINTS_PER_TASK = 32

#: Summary fields that are one number at every point (what `--metric` names most often).
SCALAR_METRICS = ("frame_time_ms", "fps", "latency_ms", "frame_time_jitter_ms", "frame_time_min_ms",
                  "frame_time_max_ms", "frames", "warmup_frames")
#: Summary fields holding numbers per GPU, queue or task (`utilization.gpu0.graphics`): which
#: members a point has depends on its experiment, so a metric under them is checked on the table.
METRIC_GROUPS = ("utilization", "memory", "task_rates_hz", "skipped_tasks", "window_ns", "fast_forward")
#: Summary fields that are not numbers: no metric, and, like every output column, no grid key.
TEXT_FIELDS = ("fidelity", "modelled_effects", "approximations", "warnings", "effects", "fast_forward.used",
               "fast_forward.why")
#: A Dask scheduler address: [scheme://]host:port (or a scheduler in this process: inproc://).
DASK_ADDRESS = re.compile(r"(?:(tcp|tls|ws|wss|ucx)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})")
DASK_INPROC = re.compile(r"inproc://[A-Za-z0-9_.:\[\]-]+/[0-9]+/[0-9]+")


class Point:
    """One combination of grid values, in grid order (`index`), known by `id`. (A slotted
    class: a 100k-point grid makes its points in a fraction of a frozen dataclass's time.)"""

    __slots__ = ("index", "keys", "id")

    def __init__(self, index: int, keys: dict[str, Any], id: str):  # noqa: A002 - the point's id
        self.index, self.keys, self.id = index, keys, id

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Point) and (self.index, self.keys, self.id) == (other.index, other.keys, other.id)

    __hash__ = None  # type: ignore[assignment]  # (its keys are a dict, as a dataclass's would be)

    def __repr__(self) -> str:
        return f"Point(index={self.index}, keys={self.keys!r}, id={self.id!r})"


def parse_grid(items: Sequence[str] | None) -> dict[str, list[Any]]:
    """``["schedule.gpus=1,2,3", "scene.width=1024,1920"]`` -> {key: [values]} (TOML values)."""
    grid: dict[str, list[Any]] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        key = key.strip()
        try:
            values = [parse_value(v.strip()) for v in text.split(",") if v.strip()]
        except InputError as exc:  # a value nested too deeply
            raise InputError(exc.detail, field=f"--grid {key}") from None
        if not sep or not key or not values:
            shown = item if len(item) <= 60 else item[:60] + "..."
            raise InputError(f"expected KEY=V1,V2,..., got {shown!r}", field="--grid")
        if key in grid:
            raise InputError(f"key {key!r} given twice", field="--grid")
        grid[key] = values
    if not grid:
        raise InputError("give at least one --grid KEY=V1,V2,...", field="--grid")
    return grid


def grid_points(grid: Mapping[str, Sequence[Any]], identity: Mapping[str, Any]) -> list[Point]:
    """The product of the grid (last key fastest); `identity` is what else makes a point's
    result (experiment bytes, base overrides, fidelity), hashed into every id: the hash of
    ``json.dumps({**identity, "point": keys}, sort_keys=True, default=str)``."""
    keys = list(grid)
    head = json.dumps(identity, sort_keys=True, default=str)
    if not identity or any(k >= "point" for k in identity):  # "point" is not the last key
        return [Point(i, dict(zip(keys, values)), _point_id({**identity, "point": dict(zip(keys, values))}))
                for i, values in enumerate(itertools.product(*(grid[k] for k in keys)))]
    # the same text as json.dumps({**identity, "point": point}, sort_keys=True), built from
    # each value's text once and joined in the keys' sorted order (a 100k-point grid would
    # spend seconds serialising); the product is taken in that order, then put in grid order
    by_name = sorted(range(len(keys)), key=lambda j: keys[j])
    frags = [[f"{json.dumps(k)}: {json.dumps(v, sort_keys=True, default=str)}" for v in grid[k]] for k in keys]
    prefix, suffix = head[:-1] + ', "point": {', "}}"
    sha = hashlib.sha256
    named = [sha(f"{prefix}{', '.join(parts)}{suffix}".encode()).hexdigest()[:20]
             for parts in itertools.product(*(frags[j] for j in by_name))]
    sizes = [len(grid[k]) for k in keys]
    # position in the sorted-order product -> index in grid order
    digits = np.indices([sizes[j] for j in by_name]).reshape(len(keys), -1)
    index = np.zeros(digits.shape[1], dtype=np.int64)
    strides = np.concatenate([np.cumprod(np.array(sizes[::-1], dtype=np.int64))[::-1][1:], [1]])
    for row, j in enumerate(by_name):
        index += digits[row] * strides[j]
    ids: list[str] = [""] * len(named)
    for pos, i in enumerate(index.tolist()):
        ids[i] = named[pos]
    values = [grid[k] for k in keys]
    return [Point(i, dict(zip(keys, combo)), pid)
            for i, (combo, pid) in enumerate(zip(itertools.product(*values), ids))]


def _point_id(blob: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()[:20]


def check_grid(grid: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any]) -> None:
    """Before the grid is enumerated: its size within MAX_SWEEP_POINTS, no key named like a
    column of the table (`point`, `error`, `wall_s`, a summary field), none also given to
    --set (the grid's value would silently win), no value given twice in one key."""
    size = math.prod(len(v) for v in grid.values())
    if size > MAX_SWEEP_POINTS:
        counts = " x ".join(str(len(v)) for v in grid.values())
        raise InputError(f"{counts} = {size:,} points; at most {MAX_SWEEP_POINTS:,} ({WHY_SWEEP})",
                         field="--grid")
    for key, values in grid.items():
        if _output_column(key):
            raise InputError(f"{key!r} names a column of the sweep's table (point, error, wall_s "
                             "and the summary's fields); a grid key is an experiment key such as "
                             "schedule.gpus", field=f"--grid {key}")
        if key in overrides:
            raise InputError("also given to --set: give it to one of them", field=f"--grid {key}")
        seen = [json.dumps(v, sort_keys=True, default=str) + type(v).__name__ for v in values]
        twice = next((v for v, k in zip(values, seen) if seen.count(k) > 1), None)
        if twice is not None:
            raise InputError(f"the value {twice!r} is given twice", field=f"--grid {key}")


def _output_column(key: str) -> bool:
    head = key.split(".")[0]
    return key in META_COLUMNS or key in SCALAR_METRICS or head in METRIC_GROUPS \
        or head in TEXT_FIELDS or key in TEXT_FIELDS


def check_metric(metric: str) -> None:
    """`--metric` before any work: a numeric summary field (or `wall_s`), or a member of a
    group of them (`utilization.gpu0.graphics`, checked again once the table exists)."""
    head = metric.split(".")[0]
    if metric in SCALAR_METRICS or metric == "wall_s":
        return
    if metric in TEXT_FIELDS or head in TEXT_FIELDS or head in ("point", "error"):
        raise InputError(f"{metric!r} is not a number; give a numeric summary field such as "
                         f"{', '.join(SCALAR_METRICS[:3])}", field="--metric")
    if head in METRIC_GROUPS and metric != head and all(metric.split(".")):
        return
    known = [*SCALAR_METRICS, "wall_s", *(f"{g}.<member>" for g in METRIC_GROUPS)]
    raise InputError(f"{metric!r} is not a summary field{did_you_mean(metric, known)}; the numeric "
                     f"ones: {', '.join(known)}", field="--metric")


def check_metric_column(df: pd.DataFrame, metric: str) -> None:
    """Once the points ran, before the table is written: some point that ran has `metric` as a
    number (a group member such as utilization.gpu3.graphics exists only where the
    experiment has it). The points stay saved, so the corrected command reruns nothing."""
    ok = df[df["error"].isna()]
    if ok.empty:
        return  # every point failed: the command reports that instead
    if metric in df and pd.api.types.is_numeric_dtype(df[metric]) \
            and not pd.api.types.is_bool_dtype(df[metric]) and ok[metric].notna().any():
        return
    numeric = [c for c in df.columns if c not in ("point", "error") and pd.api.types.is_numeric_dtype(df[c])
               and not pd.api.types.is_bool_dtype(df[c]) and c.split(".")[0] in METRIC_GROUPS]
    numeric.sort(key=lambda c: c.split(".")[0] != metric.split(".")[0])  # its own group first
    raise InputError(f"no point has a number {metric!r}{did_you_mean(metric, numeric)} (the points "
                     f"are saved: run again with another --metric, e.g. {', '.join(numeric[:4]) or 'fps'})",
                     field="--metric")


def check_dask_address(address: str) -> None:
    """A Dask scheduler address as `[scheme://]host:port`, checked before anything connects."""
    if DASK_INPROC.fullmatch(address):
        return
    m = DASK_ADDRESS.fullmatch(address)
    if m is None or not 1 <= int(m.group(3)) <= 65535:
        raise InputError(f"expected a scheduler address as [tcp://]HOST:PORT (port 1-65535), "
                         f"got {address!r}", field="--dask")


def simulate_options(fidelity: str) -> dict[str, Any]:
    """Keyword arguments for :func:`simulate` at `fidelity`, checked once before any point
    runs (a misspelt level is one error, not a failed row per point)."""
    if fidelity not in FIDELITIES:
        raise InputError(f"must be one of {', '.join(FIDELITIES)}, got {fidelity!r}", field="--fidelity")
    return {"fidelity": fidelity}


def run_point(experiment: str, overrides: Mapping[str, Any], options: Mapping[str, Any]) -> dict[str, Any]:
    """One point, in whatever process runs it: its flattened summary, or the error that a
    user would have seen for it (bad overrides, a schedule that cannot run). The experiment
    is loaded by this process's :func:`loader` for its file (parsed once, overridden in
    memory: the same experiment and errors as `load_experiment`)."""
    t0 = time.perf_counter()
    try:
        exp = loader(experiment).load(dict(overrides))
        result = simulate(exp, **options)
        summary, error = flatten(result.summary), None
    except MgpusimError as exc:
        summary, error = {}, str(exc)
    return {"summary": summary, "error": error, "wall_s": round(time.perf_counter() - t0, 6)}


def run_points(args: Sequence[tuple[str, Mapping[str, Any], Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """:func:`run_point` for each of several points (what a pool worker is handed at once)."""
    return [run_point(*a) for a in args]


def sweep(experiment: str | Path, grid: Mapping[str, Sequence[Any]], out: str | Path | None = None, *,
          overrides: Mapping[str, Any] | None = None, fidelity: str = "full", workers: int | None = None,
          dask: Any = None, progress: bool = True, metric: str = "frame_time_ms") -> pd.DataFrame:
    """Run `experiment` at every point of `grid` and return the table (one row per point).

    `out`: a folder for the saved points, `sweep.parquet`, `sweep.png` and `sweep.json`;
    resumable, and locked while the sweep runs. `workers`: local processes (1 runs in this
    process). `dask`: a Dask scheduler address or a `distributed.Client` to run the points on
    instead. Every argument is checked, and the base experiment and each grid key loaded,
    before any point runs or any file is written.
    """
    path = resolve_experiment(experiment)
    fresh_loader(path)
    if workers is not None and not 1 <= workers <= MAX_SWEEP_WORKERS:
        raise InputError(f"must be in 1..{MAX_SWEEP_WORKERS}, got {workers}", field="--workers")
    grid = {k: list(v) for k, v in grid.items()}
    if not grid or any(not v for v in grid.values()):
        raise InputError("the grid needs at least one key with at least one value", field="--grid")
    base = dict(overrides or {})
    check_grid(grid, base)
    check_metric(metric)
    if isinstance(dask, str):
        check_dask_address(dask)
    options = simulate_options(fidelity)
    if out is not None:
        from mgpusim.io.out_folder import check_out_dir  # noqa: PLC0415 - files stay at the edge
        check_out_dir(Path(out))
    check_inputs(path, grid, base)
    identity = point_identity(path, grid, base, fidelity)
    inputs = identity["inputs"]
    points = grid_points(grid, identity)
    with _dask_client(dask) as client, _store(out) as store:
        wanted = {p.id for p in points}
        records = store.load(wanted) if store else {}
        batches = store.load_batches(wanted) if store else []
        done = set(records).union(*(b["id"] for b in batches))
        todo = [p for p in points if p.id not in done]
        with _bar(len(points), len(points) - len(todo), progress) as bar, fewer_collections():
            lanes = LaneRun(path, base, grid, todo if client is None else [], fidelity, loader=loader(path),
                            workers=local_workers(workers), store=store)
            for batch in lanes:  # the analytic level over many points at once, saved per batch
                if store and not batch.attrs.get("saved"):  # (a worker process saved it)
                    store.save_batch(batch)
                batches.append(batch)
                bar.update(len(batch))
            rest = lanes.fallback if client is None else todo
            unsaved: list[tuple[Point, dict[str, Any]]] = []
            saved_at, every = time.monotonic(), float(os.environ.get("MGPUSIM_SWEEP_SAVE_S", SAVE_EVERY_S))
            for finished in _run(path, base, options, rest, workers, client, store):
                for point, record in finished:
                    records[point.id] = record
                unsaved.extend(finished)
                bar.update(len(finished))
                if store and time.monotonic() - saved_at >= every:  # one file, not one per point
                    store.save_batch(records_frame(unsaved), "single")
                    unsaved, saved_at = [], time.monotonic()
            if store and unsaved:
                store.save_batch(records_frame(unsaved), "single")
        df = table(points, records, batches)
        check_metric_column(df, metric)
        if store:
            store.finish(df, list(grid), metric, {"experiment": str(path), "grid": grid, "overrides": base,
                                                  "fidelity": fidelity, "points": len(points),
                                                  "inputs": inputs, "mgpusim": __version__})
    return df


@contextlib.contextmanager
def _store(out: str | Path | None) -> Iterator[Any]:
    """The sweep's locked folder (None without one)."""
    if out is None:
        yield None
        return
    from mgpusim.sweeps.store import PointStore  # noqa: PLC0415 - files stay at the edge

    with PointStore(Path(out)) as store:
        yield store


@contextlib.contextmanager
def _dask_client(dask: Any) -> Iterator[Any]:
    """A connected Dask client for `dask` (an address, or a client of the caller's, kept
    open), or None; an unreachable scheduler is one error, before any file is written."""
    if dask is None:
        yield None
        return
    try:
        from distributed import Client  # noqa: PLC0415
    except ModuleNotFoundError:
        raise InputError("needs the Python package 'distributed' (pip install 'mgpusim[dask]')",
                         field="--dask") from None
    if isinstance(dask, Client):
        yield dask
        return
    try:
        client = Client(dask, timeout=DASK_CONNECT_TIMEOUT)
    except (OSError, ValueError, TypeError) as exc:
        raise InputError(f"cannot reach the Dask scheduler {dask!r} ({exc})", field="--dask") from None
    try:
        yield client
    finally:
        client.close()


def point_identity(path: Path, grid: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any],
                   fidelity: str) -> dict[str, Any]:
    """What besides its keys makes a point's result, hashed into its id (:func:`grid_points`):
    the input files' hashes (:func:`input_files`), the package version, the base overrides and
    the fidelity."""
    return {"inputs": input_files(path, grid, overrides), "mgpusim": __version__, "overrides": dict(overrides),
            "fidelity": fidelity}


def input_files(path: Path, grid: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any]) -> dict[str, str]:
    """{file: sha256} of every file the sweep's points read: the experiment and the profiles
    it, --set or a `profile` grid key names. Why: with the package version, these are the
    resume key's inputs, so a point saved before one of them changed is not reused."""
    load = loader(path)
    refs = [load._table().get("profile"), overrides.get("profile"), *grid.get("profile", ())]
    return load.inputs(ref for ref in refs if isinstance(ref, str))


def check_inputs(path: Path, grid: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any]) -> None:
    """Before any point runs: the base experiment (with the overrides) loads, and each grid key
    loads with at least one of its values on that base. A broken base, or a key none of whose
    values loads (a misspelt key, a value of the wrong type), is one error: the sweep would
    otherwise fail at every point. A key only some of whose values fail is a sweep whose failing
    points say why."""
    load = loader(path).load
    load(dict(overrides))
    for key, values in grid.items():
        first_error = None
        for value in values:
            try:
                load({**overrides, key: value})
                break
            except InputError as exc:
                first_error = first_error or exc
        else:
            raise InputError(f"no value of this grid key loads on the base experiment: "
                             f"{first_error}", field=f"--grid {key}")


def table(points: Sequence[Point], records: Mapping[str, Mapping[str, Any]],
          batches: Sequence[pd.DataFrame] = ()) -> pd.DataFrame:
    """One row per point, in grid order: point, the keys, error, the summary columns, wall_s.
    `records`: points run one by one; `batches`: tables of points run together (column `id`
    and a record's fields as columns)."""
    index = {p.id: p.index for p in points}
    rows = [{"id": pid, "error": rec["error"], **rec["summary"], "wall_s": rec["wall_s"]}
            for pid, rec in records.items() if pid in index]
    parts, order = [pd.DataFrame(rows)] if rows else [], [index[r["id"]] for r in rows]
    for b in batches:
        at = np.array([index.get(pid, -1) for pid in b["id"].tolist()], dtype=np.int64)
        parts.append(b[at >= 0])
        order.extend(at[at >= 0].tolist())
    with warnings.catch_warnings():  # all-missing columns of a part: the same dtypes as rows
        warnings.simplefilter("ignore", FutureWarning)
        df = pd.concat(parts, ignore_index=True) if len(parts) > 1 else parts[0].reset_index(drop=True)
    if len(parts) > 1:  # a column's type as one table of all the rows would infer it
        for col in [c for c in df.columns if pd.api.types.is_object_dtype(df[c])]:
            df[col] = pd.Series(df[col].tolist(), index=df.index)
    df = df.drop(columns="id").iloc[np.argsort(np.asarray(order), kind="stable")].reset_index(drop=True)
    keys = list(points[0].keys)
    df.insert(0, "point", np.arange(len(points), dtype=np.int64))
    for i, key in enumerate(keys):
        df.insert(1 + i, key, [p.keys[key] for p in points])
    summary = [c for c in df.columns if c not in META_COLUMNS and c not in points[0].keys]
    scalars = [c for c in summary if "." not in c]  # in the summary's own order
    df = df[["point", *points[0].keys, "error", *scalars, *sorted(set(summary) - set(scalars)), "wall_s"]]
    for col in [c for c in df.columns if pd.api.types.is_object_dtype(df[c])]:  # one type each, for Parquet
        kinds = {type(v) for v in df[col] if v is not None and v == v}
        if kinds == {bool}:
            df[col] = df[col].astype("boolean")
        else:  # strings, or mixed values
            df[col] = df[col].map(lambda v: None if v is None or v != v else str(v)).astype("string")
    return df


def local_workers(workers: int | None) -> int:
    """The local processes a sweep runs on: as asked, else one per CPU."""
    return workers or os.cpu_count() or 1


def records_frame(finished: Sequence[tuple[Point, Mapping[str, Any]]]) -> pd.DataFrame:
    """Points run one by one as one table in the form of a batch of lanes (column `id`, then
    `error`, `wall_s` and the summary's columns): what the store saves them as."""
    return pd.DataFrame([{"id": p.id, "error": rec["error"], "wall_s": rec["wall_s"], **rec["summary"]}
                         for p, rec in finished])


def _run(path: Path, base: Mapping[str, Any], options: Mapping[str, Any], todo: list[Point],
         workers: int | None, client: Any, store: Any) -> Iterator[list[tuple[Point, dict[str, Any]]]]:
    """[(point, record), ...] as points finish, on Dask, a process pool (a few points handed
    to a worker at once), or here."""
    if not todo:
        return
    where = str(path.resolve()) if client is not None else str(path)  # Dask workers have their own cwd
    args = [(where, {**base, **p.keys}, dict(options)) for p in todo]
    if client is not None:
        futures = {client.submit(run_point, *a, pure=False): p for p, a in zip(todo, args)}
        from distributed import as_completed as dask_completed  # noqa: PLC0415
        for fut in dask_completed(futures):
            yield [(futures[fut], fut.result())]
        return
    workers = min(local_workers(workers), len(todo))
    if workers == 1:
        for point, a in zip(todo, args):
            yield [(point, run_point(*a))]
        return
    loader(where)._table()  # read before the workers fork: each inherits it parsed
    per_task = max(1, min(POINTS_PER_TASK, len(todo) // (4 * workers)))
    with local_pool(workers, store) as pool:
        chunks: dict[Any, list[Point]] = {pool.submit(run_points, args[lo:lo + per_task]): todo[lo:lo + per_task]
                                          for lo in range(0, len(todo), per_task)}
        try:
            for fut in as_completed(chunks):
                yield list(zip(chunks[fut], fut.result()))
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


@contextlib.contextmanager
def _bar(total: int, done: int, enabled: bool) -> Iterator[Any]:
    """A tqdm bar (points done of total, rate and ETA) on stderr."""
    from tqdm import tqdm  # noqa: PLC0415

    with tqdm(total=total, initial=done, desc="sweep", unit="point", disable=not enabled,
              dynamic_ncols=True) as bar:
        yield bar
