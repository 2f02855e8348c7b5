"""Sweeps: one experiment run over the product of a grid of overrides.

``sweep("experiments/sort_first_tc1.toml", {"schedule.gpus": [1, 2, 3], "scene.width": [1024, 1920]})``
runs six points and returns one row per point: the point's keys, every summary field
(flattened to dotted columns: ``utilization.gpu0.graphics``) and an ``error`` column, so that
a point whose override is invalid is a row, not the end of the sweep.

Points run in local processes, or on a Dask cluster. Given an output folder, each finished
point is saved at once (see :mod:`mgpusim.io.sweep_store`) and a sweep started again over the
same folder skips it: a sweep killed at any moment loses no finished point and recomputes none.
A point is known by a hash of the experiment file's bytes, the base overrides, its keys and
the fidelity, so editing the experiment file recomputes everything; a changed profile file
is not noticed (use a fresh folder).
"""
from __future__ import annotations

import hashlib
import itertools
import json
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import pandas as pd

from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError, MgpusimError
from mgpusim.schedules.experiment import load_experiment, parse_value
from mgpusim.sim.effects import FIDELITIES
from mgpusim.sim.simulation import simulate

#: How long to try reaching a Dask scheduler before giving up.
DASK_CONNECT_TIMEOUT = "10s"

#: What a point's record holds besides its summary.
META_COLUMNS = ("point", "error", "wall_s")


@dataclass(frozen=True)
class Point:
    """One combination of grid values, in grid order (`index`), known by `id`."""

    index: int
    keys: dict[str, Any]
    id: str


def parse_grid(items: Sequence[str] | None) -> dict[str, list[Any]]:
    """``["schedule.gpus=1,2,3", "scene.width=1024,1920"]`` -> {key: [values]} (TOML values)."""
    grid: dict[str, list[Any]] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        key = key.strip()
        values = [parse_value(v.strip()) for v in text.split(",") if v.strip()]
        if not sep or not key or not values:
            raise InputError(f"expected KEY=V1,V2,..., got {item!r}", field="--grid")
        if key in grid:
            raise InputError(f"key {key!r} given twice", field="--grid")
        grid[key] = values
    if not grid:
        raise InputError("give at least one --grid KEY=V1,V2,...", field="--grid")
    return grid


def grid_points(grid: Mapping[str, Sequence[Any]], identity: Mapping[str, Any]) -> list[Point]:
    """The product of the grid (last key fastest); `identity` is what else makes a point's
    result (experiment bytes, base overrides, fidelity), hashed into every id."""
    keys = list(grid)
    points = []
    for index, values in enumerate(itertools.product(*(grid[k] for k in keys))):
        point = dict(zip(keys, values))
        blob = json.dumps({**identity, "point": point}, sort_keys=True, default=str)
        points.append(Point(index, point, hashlib.sha256(blob.encode()).hexdigest()[:20]))
    return points


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts and lists as dotted columns: {"a": {"b": 1}, "w": [2, 3]} ->
    {"a.b": 1, "w.0": 2, "w.1": 3}."""
    if isinstance(value, Mapping):
        items: Iterable[tuple[Any, Any]] = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return {prefix: value}
    out: dict[str, Any] = {}
    for k, v in items:
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def simulate_options(fidelity: str) -> dict[str, Any]:
    """Keyword arguments for :func:`simulate` at `fidelity`, checked once before any point
    runs (a misspelt level is one error, not a failed row per point)."""
    if fidelity not in FIDELITIES:
        raise InputError(f"must be one of {', '.join(FIDELITIES)}, got {fidelity!r}", field="--fidelity")
    return {"fidelity": fidelity}


def run_point(experiment: str, overrides: Mapping[str, Any], options: Mapping[str, Any]) -> dict[str, Any]:
    """One point, in whatever process runs it: its flattened summary, or the error that a
    user would have seen for it (bad overrides, a schedule that cannot run)."""
    t0 = time.perf_counter()
    try:
        result = simulate(load_experiment(experiment, dict(overrides)), **options)
        summary, error = flatten(result.summary), None
    except MgpusimError as exc:
        summary, error = {}, str(exc)
    return {"summary": summary, "error": error, "wall_s": round(time.perf_counter() - t0, 6)}


def sweep(experiment: str | Path, grid: Mapping[str, Sequence[Any]], out: str | Path | None = None, *,
          overrides: Mapping[str, Any] | None = None, fidelity: str = "full", workers: int | None = None,
          dask: Any = None, progress: bool = True, metric: str = "frame_time_ms") -> pd.DataFrame:
    """Run `experiment` at every point of `grid` and return the table (one row per point).

    `out`: a folder for the saved points, `sweep.parquet`, `sweep.png` and `sweep.json`;
    resumable. `workers`: local processes (1 runs in this process). `dask`: a Dask
    scheduler address or a `distributed.Client` to run the points on instead.
    """
    path = resolve_experiment(experiment)
    if workers is not None and workers < 1:
        raise InputError(f"must be >= 1, got {workers}", field="--workers")
    grid = {k: list(v) for k, v in grid.items()}
    if not grid or any(not v for v in grid.values()):
        raise InputError("the grid needs at least one key with at least one value", field="--grid")
    base = dict(overrides or {})
    options = simulate_options(fidelity)
    check_inputs(path, grid, base)
    identity = {"experiment": hashlib.sha256(path.read_bytes()).hexdigest(), "overrides": base,
                "fidelity": fidelity}
    points = grid_points(grid, identity)
    store = None
    if out is not None:
        from mgpusim.io.sweep_store import PointStore  # noqa: PLC0415 - files stay at the edge

        store = PointStore(Path(out))
    records = store.load({p.id for p in points}) if store else {}
    todo = [p for p in points if p.id not in records]
    for point, record in _progress(_run(path, base, options, todo, workers, dask), len(points),
                                   len(points) - len(todo), progress):
        records[point.id] = record
        if store:
            store.save(point.id, {"keys": point.keys, **record})
    df = table(points, records)
    if store:
        store.finish(df, list(grid), metric, {"experiment": str(path), "grid": grid, "overrides": base,
                                              "fidelity": fidelity, "points": len(points)})
    return df


def check_inputs(path: Path, grid: Mapping[str, Sequence[Any]], overrides: Mapping[str, Any]) -> None:
    """Before any point runs: the base experiment (with the overrides) loads, and each grid key
    loads with at least one of its values on that base. A broken base, or a key none of whose
    values loads (a misspelt key, a value of the wrong type), is one error: the sweep would
    otherwise fail at every point. A key only some of whose values fail is a sweep whose failing
    points say why."""
    load_experiment(path, dict(overrides))
    for key, values in grid.items():
        first_error = None
        for value in values:
            try:
                load_experiment(path, {**overrides, key: value})
                break
            except InputError as exc:
                first_error = first_error or exc
        else:
            raise InputError(f"no value of this grid key loads on the base experiment: "
                             f"{first_error}", field=f"--grid {key}")


def table(points: Sequence[Point], records: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """One row per point, in grid order: point, the keys, error, the summary columns, wall_s."""
    rows = []
    for p in points:
        rec = records[p.id]
        rows.append({"point": p.index, **p.keys, "error": rec["error"], **rec["summary"],
                     "wall_s": rec["wall_s"]})
    df = pd.DataFrame(rows)
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


def _run(path: Path, base: Mapping[str, Any], options: Mapping[str, Any], todo: list[Point],
         workers: int | None, dask: Any) -> Iterator[tuple[Point, dict[str, Any]]]:
    """(point, record) as each point finishes, on Dask, a process pool, or here."""
    if not todo:
        return
    where = str(path.resolve()) if dask is not None else str(path)  # Dask workers have their own cwd
    args = [(where, {**base, **p.keys}, dict(options)) for p in todo]
    if dask is not None:
        yield from _run_dask(todo, args, dask)
        return
    workers = min(workers or os.cpu_count() or 1, len(todo))
    if workers == 1:
        for point, a in zip(todo, args):
            yield point, run_point(*a)
        return
    with ProcessPoolExecutor(max_workers=workers, initializer=_exit_with_parent, initargs=(os.getpid(),)) as pool:
        futures = {pool.submit(run_point, *a): p for p, a in zip(todo, args)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _exit_with_parent(parent: int) -> None:
    """In a pool worker: exit when the sweep's process is gone (killed with SIGKILL, its
    workers would otherwise wait on their queue forever)."""
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)
    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def _run_dask(todo: list[Point], args: list[tuple], dask: Any) -> Iterator[tuple[Point, dict[str, Any]]]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed  # noqa: PLC0415
    except ModuleNotFoundError:
        raise InputError("needs the Python package 'distributed' (pip install 'mgpusim[dask]')",
                         field="--dask") from None
    client = dask if isinstance(dask, Client) else None
    try:
        if client is None:
            try:
                client = Client(dask, timeout=DASK_CONNECT_TIMEOUT)
            except OSError as exc:
                raise InputError(f"cannot reach the Dask scheduler {dask!r} ({exc})", field="--dask") from None
        futures = {client.submit(run_point, *a, pure=False): p for p, a in zip(todo, args)}
        for fut in dask_completed(futures):
            yield futures[fut], fut.result()
    finally:
        if client is not None and client is not dask:
            client.close()


def _progress(items: Iterator, total: int, done: int, enabled: bool) -> Iterator:
    """A tqdm bar (points done of total, rate and ETA) on stderr around `items`."""
    from tqdm import tqdm  # noqa: PLC0415

    with tqdm(total=total, initial=done, desc="sweep", unit="point", disable=not enabled,
              dynamic_ncols=True) as bar:
        for item in items:
            yield item
            bar.update(1)
