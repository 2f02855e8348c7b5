"""The machine's own speed during a job: a short reference probe, measured again at every step.

Why: a job compares times measured minutes apart (the microbenchmarks, then each round of
runs), and a model fitted on one part can only predict another if the machine ran at one speed
throughout. A shared virtual machine does not always: on our 2-core development machine one
job's mesh passes ran at twice the time of the day before, and faster again by its held-out
runs, which made every error of that job meaningless (its calibration runs were 8 % off their
own fit). On lavapipe studies the probe (a fragment loop and a mesh on one GPU, half a second)
is measured before and after the microbenchmarks, before each round of runs and after the
last; the report shows how far it moved and warns when it moved more than `DRIFT_LIMIT`.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Sequence

import pandas as pd

from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError, UnsteadyMachineError

#: The reference passes: one bound by fragment shading, one by geometry and memory.
PROBE: tuple[tuple[str, dict[str, Any]], ...] = (
    ("fragment_loop", {"width": 256, "height": 192, "iterations": 500}),
    ("mesh", {"width": 256, "height": 192, "triangles": 10_000}),
)
PROBE_REPS = 8
#: Discarded first repetitions: lavapipe's mesh passes get faster over their first ~10 frames.
PROBE_WARMUP = 12
#: A job whose probe moved more than this (slowest / fastest - 1, per pass) gets a warning.
DRIFT_LIMIT = 0.10
#: A steadiness check before a job: this many probes, this far apart (about half a minute).
CHECKS = 5
CHECK_PAUSE_S = 3.0
#: Waiting for a steady machine: the pause between two steadiness checks.
RETRY_PAUSE_S = 60.0
#: The longest wait a job may ask for (a day).
MAX_WAIT_MINUTES = 24 * 60
FILE = "speed_probe.csv"
COLUMNS = ["point", "pass", "median_ms", "unix_time"]


def measure_probe(point: str, threads: int | None) -> list[dict[str, Any]]:
    """The probe's median pass times now, on one fresh lavapipe (or Vulkan) GPU."""
    from mgpusim.measure import microbench as m  # noqa: PLC0415 - Vulkan is needed only to measure
    from mgpusim.real.vulkan.machine import close_gpus, make_gpus  # noqa: PLC0415

    gpus = make_gpus(1, lp_threads=None if threads is None else [threads])
    try:
        rows = []
        for name, params in PROBE:
            df = m.measure(name, gpus, {k: [v] for k, v in params.items()}, reps=PROBE_REPS,
                           warmup=PROBE_WARMUP)
            rows.append({"point": point, "pass": name,
                         "median_ms": float(df["duration_ns"].median()) / 1e6,
                         "unix_time": round(time.time(), 1)})
        return rows
    finally:
        close_gpus(gpus)


class Prober:
    """The probe on one lavapipe GPU kept open across a job's runs (`with Prober(t) as p:
    p.probe(point)`): its shaders built and its passes warmed once, so that each probe between
    two runs takes ~0.1 s and only `PROBE_REPS` repetitions.

    Why not a fresh GPU each time (`measure_probe`): the first probe in a process reads ~10 %
    slow, and on a quiet machine two fresh-GPU fragment-loop probes in a row differed by a median
    4 % (90th percentile 12 %), two on one kept GPU by 1.6 % (3 %): the per-run probe must be
    steadier than the speed changes it is there to catch."""

    def __init__(self, threads: int) -> None:
        self.threads = threads
        self._gpus: list[Any] = []
        self._warm = False

    def __enter__(self) -> "Prober":
        from mgpusim.real.vulkan.machine import make_gpus  # noqa: PLC0415
        self._gpus = make_gpus(1, lp_threads=[self.threads])
        return self

    def __exit__(self, *exc: object) -> None:
        from mgpusim.real.vulkan.machine import close_gpus  # noqa: PLC0415
        close_gpus(self._gpus)
        self._gpus = []

    def probe(self, point: str) -> list[dict[str, Any]]:
        """The probe's median pass times now (rows as `measure_probe`'s)."""
        from mgpusim.measure import microbench as m  # noqa: PLC0415
        rows = []
        for name, params in PROBE:
            df = m.measure(name, self._gpus, {k: [v] for k, v in params.items()}, reps=PROBE_REPS,
                           warmup=2 if self._warm else PROBE_WARMUP)
            rows.append({"point": point, "pass": name,
                         "median_ms": float(df["duration_ns"].median()) / 1e6,
                         "unix_time": round(time.time(), 1)})
        self._warm = True
        return rows


def check_steady(threads: int | None, limit: float, progress: Callable[[str], None],
                 checks: int | None = None, pause_s: float | None = None,
                 probe: Callable[[str, int | None], list[dict[str, Any]]] | None = None,
                 ) -> list[dict[str, Any]]:
    """The probe `checks` times (default CHECKS), `pause_s` apart (CHECK_PAUSE_S); its rows if
    no pass moved more than `limit` (slowest / fastest - 1), else UnsteadyMachineError naming the
    pass and its times. `probe` stands in for the real one in tests.

    Why before the job: a job on a machine whose speed moves takes as long and says nothing about
    the model (the report's warning comes minutes later); half a minute of probes tells first."""
    _check_limit(threads, limit)
    rows, finding = _try_steady(threads, limit, progress, checks, pause_s, probe)
    if finding is not None:
        raise UnsteadyMachineError(_unsteady_message(finding))
    return rows


def wait_steady(threads: int | None, limit: float, minutes: float,
                progress: Callable[[str], None], *, retry_pause_s: float = RETRY_PAUSE_S,
                checks: int | None = None, pause_s: float | None = None,
                probe: Callable[[str, int | None], list[dict[str, Any]]] | None = None,
                clock: Callable[[], float] = time.monotonic,
                sleep: Callable[[float], None] = time.sleep) -> list[dict[str, Any]]:
    """The steadiness check, tried again every `retry_pause_s` until it passes (its rows) or
    `minutes` have gone by since the first try (UnsteadyMachineError: the last try's finding and
    how long it waited). `probe`, `clock` and `sleep` stand in for the real ones in tests.

    Why: a shared machine that drifts now is often steady an hour later, and a job started by
    hand when it looks quiet may still catch a drift; the job itself can wait for a quiet spell."""
    _check_limit(threads, limit)
    if not 0 < minutes <= MAX_WAIT_MINUTES:
        raise InputError(f"expected minutes to wait, more than 0 and at most "
                         f"{MAX_WAIT_MINUTES}, got {minutes}", field="--wait-steady")
    start, tries = clock(), 0
    while True:
        tries += 1
        rows, finding = _try_steady(threads, limit, progress, checks, pause_s, probe)
        if finding is None:
            return rows
        waited = clock() - start
        if waited + retry_pause_s > minutes * 60:
            raise UnsteadyMachineError(
                f"{_unsteady_message(finding)} (still after {tries} tries over "
                f"{waited / 60:.0f} of the {minutes:g} minutes allowed by --wait-steady)")
        progress(f"not steady yet: {finding}; next try in {retry_pause_s:.0f} s "
                 f"({waited / 60:.0f} of {minutes:g} minutes waited)")
        sleep(retry_pause_s)


def _check_limit(threads: int | None, limit: float) -> None:
    if threads is None:
        raise InputError("the steadiness check needs a lavapipe study (its GPUs are this "
                         "host's cores); this study measures real GPUs", field="--steady-check")
    if not 0 < limit < 10:
        raise InputError(f"expected a fraction such as 0.1 (10 %), got {limit}",
                         field="--steady-check")


def _try_steady(threads: int | None, limit: float, progress: Callable[[str], None],
                checks: int | None, pause_s: float | None,
                probe: Callable[[str, int | None], list[dict[str, Any]]] | None,
                ) -> tuple[list[dict[str, Any]], str | None]:
    """One steadiness check: its probe rows, and what moved more than `limit` (None: nothing)."""
    checks = CHECKS if checks is None else checks
    pause_s = CHECK_PAUSE_S if pause_s is None else pause_s
    probe = probe or measure_probe
    rows: list[dict[str, Any]] = []
    for i in range(checks):
        progress(f"steadiness check {i + 1}/{checks}")
        rows += probe(f"steadiness check {i + 1} of {checks}", threads)
        if i + 1 < checks:
            time.sleep(pause_s)
    probes = pd.DataFrame(rows, columns=COLUMNS)
    worst, name = worst_drift(probes)
    if worst > limit:
        times = probes.loc[probes["pass"] == name, "median_ms"]
        return rows, (f"the {name} probe took {times.min():.2f}-{times.max():.2f} ms over "
                      f"{checks} checks ({worst:.0%}, more than the {limit:.0%} allowed by "
                      f"--steady-check)")
    progress(f"steady: every probe within {worst:.0%}")
    return rows, None


def _unsteady_message(finding: str) -> str:
    return (f"the machine's speed moved before the job: {finding}; its errors would carry that. "
            f"Run it when the machine is quiet, or without --steady-check to measure anyway")


def append_probe(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Add `rows` to the probe table at `path` (written whole each time, or not at all: a job
    cut short keeps every probe it took)."""
    from mgpusim.io.writers import append_rows  # noqa: PLC0415

    append_rows(path, read_probes([path]), rows, COLUMNS)


def read_probes(paths: Sequence[Path]) -> pd.DataFrame:
    """The probe rows of every existing table among `paths` (on disk, or in a packed folder
    above it), in order."""
    frames = [run_archive.read_table(p) for p in paths if run_archive.is_file(p)]
    frames = [f for f in frames if not f.empty]
    if not frames:
        return pd.DataFrame(columns=COLUMNS)
    return pd.concat(frames, ignore_index=True)


def drift(probes: pd.DataFrame) -> pd.DataFrame:
    """Per probe point (rows, in order) and pass (columns): the time relative to the pass's
    first probe."""
    table = probes.pivot_table(index="point", columns="pass", values="median_ms", sort=False)
    return table / table.iloc[0]


def worst_drift(probes: pd.DataFrame) -> tuple[float, str]:
    """The largest slowest/fastest - 1 over the passes, and that pass."""
    spread = probes.groupby("pass")["median_ms"].agg(lambda s: s.max() / s.min() - 1)
    return float(spread.max()), str(spread.idxmax())


def drift_warning(probes: pd.DataFrame, limit: float = DRIFT_LIMIT) -> str | None:
    """One line when a probe moved more than `limit` during the job, else None."""
    if probes.empty:
        return None
    worst, name = worst_drift(probes)
    if worst <= limit:
        return None
    return (f"the machine's speed moved during this job (the {name} probe by {worst:.0%}, more "
            f"than {limit:.0%})")


def report_lines(probes: pd.DataFrame, limit: float = DRIFT_LIMIT) -> list[str]:
    """The report's section on the machine's speed (nothing without probes)."""
    if probes.empty:
        return []
    rel = drift(probes)
    lines = ["## The machine's speed during the job", "",
             "A reference fragment loop and mesh (one GPU, median of "
             f"{PROBE_REPS}), measured at each step; times relative to the first probe.", "",
             "| point | " + " | ".join(rel.columns) + " |", "|---" * (len(rel.columns) + 1) + "|"]
    lines += [f"| {point} | " + " | ".join(f"{v:.2f}" for v in row) + " |"
              for point, row in rel.iterrows()]
    lines.append("")
    warning = drift_warning(probes, limit)
    if warning is not None:
        lines.append(f"**Warning: {warning}**: the microbenchmarks and the runs were measured at "
                     f"different speeds, and every raw error below includes that (the "
                     f"speed-normalized ones scale each run by its own probe). Run the job again "
                     f"on a quiet machine before reading the raw errors as the model's.")
    else:
        lines.append(f"The probes stayed within {worst_drift(probes)[0]:.0%} of each other: one "
                     f"machine speed throughout.")
    return lines + [""]
