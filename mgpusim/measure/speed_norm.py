"""Speed-normalized prediction on lavapipe: each run predicted at the machine's speed of its own
moment, and the flag on a run whose speed is the least known.

The scale of a run is its probe over the probe at calibration: the fragment-loop probe
(:mod:`mgpusim.measure.speed_probe`), the faster of the probes just before and just after the
run, over the median of the same over the calibration runs the comparison uses (the
runs whose passes the profile's costs were refitted on; those the flag below trusts). The profile is scaled by it
(:func:`mgpusim.model.speed_scale.at_speed`: passes, copies and the host's CPU work) and the run
is simulated again (:func:`mgpusim.validation.crossvalidate.normalized`); the raw error stays
beside the normalized one.

The speed flag (the thresholds' reasons are at the constants): a run is flagged when
  * its probes before and after disagree by more than DISAGREEMENT_LIMIT: the machine changed
    speed during the run, and which speed its compared window ran at is known only within
    that; or
  * other processes used more than OTHER_CORES_LIMIT cores on average during it: a process beside
    the run slows its passes unevenly, so no single scale describes the run.
A flag is shown beside the run; it no longer takes the run out of the verdict. The verdict
(:mod:`mgpusim.studies.verdict`) keeps every run and gives the prediction a band from each run's
probe disagreement and its repeats' spread, so a run whose speed moved widens the band.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np
import pandas as pd

#: Why 10 %: two fragment-loop probes back to back differ by a median 1.6 % (90th percentile
#: 3 %), so 10 % is a real change of speed, not the probe's noise; and the window compared of a
#: run whose speed moved by d may lie anywhere between its two probes, up to d from the faster
#: one: at 10 % the size of the errors the verdict is about (held-out medians of 3-6 %).
#: Measured since: a run apart, in a quiet job, ~30 % of the probes moved more (the machine's
#: 0.25-2 s phases), so a quiet job has that share flagged
#: (docs/journal/2026-11-26_speed_normalized.md); their bands are the widest.
DISAGREEMENT_LIMIT = 0.10
#: Why 0.25 cores: an idle machine shows 0.01-0.02 cores of other work (the kernel's own); at a
#: quarter core others hold an eighth of the two cores, enough to slow a pass filling both cores
#: ~12 % and a one-thread copy not at all, a misscaling of the size of the verdict's points.
OTHER_CORES_LIMIT = 0.25


@dataclass(frozen=True)
class RunSpeed:
    """One compared run's speed: its probes (ms), the reference, what else loaded the cores."""

    config: str
    run: str
    before_ms: float
    after_ms: float
    reference_ms: float
    other_cores: float = float("nan")
    steal_cores: float = float("nan")

    @property
    def probe_ms(self) -> float:
        """The probe at the run: the faster of the probes just before and after it.

        Why the faster, not a mean: what is compared is the run's steady window, the fast end
        of its repeats (outside work and the machine's slow phases only add time), and of the
        two probes the faster is the one nearer that state; a probe slowed by a passing slow
        phase says nothing about the window. Measured on three lavapipe main jobs of
        2026-11-27 on a drifting machine (jobs main_job_2026-11-27_* of
        data/lavapipe/history/main_jobs.parquet): their normalized medians over all runs
        4.7-5.4 % (calibration) and 5.2-6.3 % (held out), with the geometric mean 5.6-11.7 %
        and 5.1-7.7 %."""
        return min(self.before_ms, self.after_ms)

    @property
    def ratio(self) -> float:
        """How much slower the machine was at this run than at calibration (the scale)."""
        return self.probe_ms / self.reference_ms

    @property
    def disagreement(self) -> float:
        """How far the probes before and after the run differ (slower / faster - 1)."""
        return max(self.before_ms, self.after_ms) / min(self.before_ms, self.after_ms) - 1

    def flag(self) -> str:
        """Why this run's normalization cannot be trusted ('' where it can)."""
        reasons = []
        if self.disagreement > DISAGREEMENT_LIMIT:
            reasons.append(f"speed moved {self.disagreement:.0%} during the run "
                           f"(> {DISAGREEMENT_LIMIT:.0%})")
        if self.other_cores > OTHER_CORES_LIMIT:  # NaN (unknown) compares False
            reasons.append(f"other processes used {self.other_cores:.2f} cores "
                           f"(> {OTHER_CORES_LIMIT:g})")
        return "; ".join(reasons)


def reference_ms(table: pd.DataFrame, runs: Iterable[tuple[str, str]]) -> float | None:
    """The probe at calibration: the median over `runs` ((config, run)) of each run's probe in
    `table` (run_speed.csv rows), over the runs the rule trusts where there are any (a run
    measured beside another process would set the reference at a speed no steady run had);
    None where none of them has a row."""
    probes = [p for p in (speed_row(table, config, run, 1.0) for config, run in runs) if p is not None]
    trusted = [p for p in probes if not p.flag()] or probes
    return float(np.median([p.probe_ms for p in trusted])) if trusted else None


def speed_row(table: pd.DataFrame, config: str, run: str, reference: float) -> RunSpeed | None:
    """The speed of run `run` of `config` in `table`, against `reference` ms (None: no row)."""
    rows = table[(table["config"] == config) & (table["run"] == run)] if not table.empty else table
    if rows.empty:
        return None
    r = rows.iloc[-1]
    return RunSpeed(config, run, float(r["before_ms"]), float(r["after_ms"]), reference,
                    float(r["other_cores"]), float(r["steal_cores"]))
