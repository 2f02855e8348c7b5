"""The analytic level's affine stretch (mgpusim/sim/affine.py) reports what frame-by-frame
evaluation reports: the same trace, frames table and summary (the repeat found included), on
runs where it fills the frames in and on runs where a decision flips before the end."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_experiment, simulate
from mgpusim.sim import affine
from mgpusim.sim.analytic import _Recurrence

ROOT = Path(__file__).resolve().parents[1]
CASES = [("sort_first_tc1", {}), ("sort_first_tc1", {"schedule.frames": 400}),
         ("sort_last_tc1", {}), ("lavapipe/sort_first", {"schedule.frames": 100})]
CASES += [("afr_tc1", {"schedule.gpus": g, "profile.gpu_count": max(g, 3), "schedule.frames_in_flight": g,
                       "schedule.frames": n}) for g in (2, 4, 7) for n in (30, 500)]


def run(name: str, overrides: dict, record: bool, monkeypatch: pytest.MonkeyPatch, stretch: bool) -> tuple:
    used = []
    real = _Recurrence.stretch_to_end

    def spy(self: _Recurrence, f: int) -> bool:
        done = stretch and real(self, f)
        used.append(done)
        return done
    monkeypatch.setattr(_Recurrence, "stretch_to_end", spy)
    result = simulate(load_experiment(ROOT / "experiments" / f"{name}.toml", overrides or None),
                      fidelity="analytic", record_trace=record)
    return result, any(used)


@pytest.mark.parametrize(("name", "overrides"), CASES)
@pytest.mark.parametrize("record", [True, False])
def test_stretch_equals_frame_by_frame(name: str, overrides: dict, record: bool,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    fast, _ = run(name, overrides, record, monkeypatch, stretch=True)
    slow, _ = run(name, overrides, record, monkeypatch, stretch=False)
    assert fast.summary == slow.summary
    pd.testing.assert_frame_equal(fast.frames, slow.frames)
    pd.testing.assert_frame_equal(fast.trace, slow.trace)


def test_stretch_fills_the_shipped_sort_first_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """TC1 sort-first's 60 frames: the latency grows by the same amount every frame, no state
    repeats, and the stretch fills in every frame from the fifth."""
    _, used = run("sort_first_tc1", {}, True, monkeypatch, stretch=True)
    assert used


def test_lines_compare_over_their_whole_range() -> None:
    x = affine.Lin(10, -3, 3)  # 10, 7, 4, 1
    assert x > 0 and not x < 1 - 1
    with pytest.raises(affine.Indefinite) as flips:
        affine.Lin(10, -3, 4) > 0  # noqa: B015 - -2 at j = 4
    assert flips.value.last == 3
    assert affine.Lin(5, 0, 9) == 5 and affine.Lin(5, 2, 9) - affine.Lin(1, 2, 9) == 4
    assert affine.solve((affine.Lin(1, 2, 10), "a"), (7, "a"), 10) == {3}
    assert affine.solve((affine.Lin(1, 2, 10), "a"), (8, "a"), 10) == set()
