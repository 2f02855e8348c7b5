"""The advice validation's logic (mgpusim/advise/on_hardware.py) offline: the simulator
stands in for the real runs (`dry_run`), on an NVIDIA frame of the H100 entry point."""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.advise.on_hardware import Frame, Setup, collect, order_matches, pair_agreement, validate

ROOT = Path(__file__).resolve().parents[1]


def _table(predicted: list[float], measured: list[float]) -> pd.DataFrame:
    return pd.DataFrame({"predicted_ms": predicted, "measured_ms": measured})


def test_pairs_within_the_tie_predict_no_order() -> None:
    # 10 and 10.2 are tied (5 %): their measured order is free; both are predicted below 20.
    table = _table([10.0, 10.2, 20.0], [11.0, 9.0, 25.0])
    assert pair_agreement(table, 0.05) == (2, 2)
    assert order_matches(table, 0.05)
    # with no tie, 10 before 10.2 is predicted, and measured the other way round
    assert pair_agreement(table, 0.0) == (2, 3)
    assert not order_matches(table, 0.0)


def test_an_unmeasured_option_is_left_out_of_the_pairs() -> None:
    table = _table([10.0, 20.0, 5.0], [11.0, 5.0, math.nan])
    assert pair_agreement(table, 0.05) == (0, 1)


@pytest.fixture()
def setup() -> Setup:
    frame = Frame("fragment loop", ROOT / "experiments" / "h100_x4" / "sort_first.toml",
                  {"schedule.gpus": 1, "scene.passes.0.iterations": 200})
    return Setup(profile=ROOT / "hardware_profiles" / "h100_x4.toml", frames=(frame,), max_gpus=2,
                 repeats=2, frames_per_run=12, workers=1, dry_run=True)


def test_a_dry_run_measures_every_candidate_each_round_and_resumes(setup: Setup, tmp_path: Path) -> None:
    results = validate(setup, tmp_path, log=lambda _: None)
    runs = pd.read_csv(tmp_path / "runs.csv")
    assert len(results) >= 3 and results["option"].is_unique
    assert (results["family"] == "one GPU").sum() == 1 and results["family"].is_unique
    assert sorted(runs["round"].unique()) == [1, 2]
    assert len(runs) == 2 * len(results)
    assert results["measured_ms"].notna().all() and results["predicted_ms"].notna().all()
    assert sorted(results["predicted_rank"]) == list(range(1, len(results) + 1))
    # a second call finds the frame done: no run more, the same results
    again = validate(setup, tmp_path, log=lambda _: None)
    assert len(pd.read_csv(tmp_path / "runs.csv")) == len(runs)
    pd.testing.assert_frame_equal(again, collect(setup, tmp_path, lambda _: None))
    assert "of 1 frames" in (tmp_path / "summary.txt").read_text()
    assert (tmp_path / "frames" / "fragment_loop_advice.csv").exists()


def test_no_frame_starts_past_the_deadline(setup: Setup, tmp_path: Path) -> None:
    lines: list[str] = []
    results = validate(setup, tmp_path, deadline_s=-1, log=lines.append)
    assert results.empty and not (tmp_path / "runs.csv").exists()
    assert any("past the deadline" in line for line in lines)


def test_a_later_round_that_measures_an_option_clears_its_first_failure(setup: Setup, tmp_path: Path,
                                                                        monkeypatch) -> None:
    """One round's failure (a driver hiccup) stays in runs.csv; the option's row keeps the
    round that measured it and no error."""
    import mgpusim.advise.on_hardware as av
    real, failed = av.measure, []

    def flaky(setup_, path, overrides, out=None):
        if out is None and not failed:  # the first option run of round 1
            failed.append(True)
            raise RuntimeError("device lost")
        return real(setup_, path, overrides, out)
    monkeypatch.setattr(av, "measure", flaky)
    results = validate(setup, tmp_path, log=lambda _: None)
    runs = pd.read_csv(tmp_path / "runs.csv")
    assert runs["error"].fillna("").str.contains("device lost").sum() == 1
    assert results["measured_ms"].notna().all() and results["error"].isna().all()


def test_an_option_the_model_cannot_predict_keeps_the_frame_s_table(setup: Setup, tmp_path: Path,
                                                                   monkeypatch) -> None:
    """A prediction that fails (NaN) leaves that option unranked; the frame's real runs are
    written all the same."""
    import mgpusim.advise.on_hardware as av
    real = av.evaluate

    def one_nan(*args, **kwargs):
        rows = real(*args, **kwargs)
        rows[-1] = {**rows[-1], "frame_time_ms": math.nan}
        return rows
    monkeypatch.setattr(av, "evaluate", one_nan)
    results = validate(setup, tmp_path, log=lambda _: None)
    assert results["predicted_rank"].isna().sum() == 1
    assert (tmp_path / "frames" / "fragment_loop.csv").exists()
