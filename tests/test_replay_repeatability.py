"""experiments/replay_repeatability.py: the floor under the replay error over sets of runs."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("replay_repeatability", ROOT / "experiments" / "replay_repeatability.py")
rr = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rr)


def _errors() -> pd.DataFrame:
    """Two configurations over three sets: `steady` moves by 0.02 in all, `noisy` by 0.20."""
    rows = [("a", "steady", 0.01), ("b", "steady", 0.03), ("c", "steady", 0.02),
            ("a", "noisy", -0.10), ("b", "noisy", 0.10), ("c", "noisy", 0.04),
            ("a", "one_set_only", 0.5)]
    return pd.DataFrame([{"set": s, "half": "held out", "config": c, "replay": e, "prediction": 0.0}
                         for s, c, e in rows])


def test_spread_is_half_the_range_over_the_sets_seen_in_all():
    table = rr.spread(_errors())
    assert list(table.index.get_level_values("config")) == ["steady", "noisy"]  # the one-set config dropped
    assert table.loc[("held out", "noisy"), "half_range"] == pytest.approx(0.10)
    assert table.loc[("held out", "steady"), "half_range"] == pytest.approx(0.01)


def test_floor_measures_each_set_from_the_configurations_mid_range():
    out = rr.floor(_errors())
    # noisy's mid-range is 0: sets a and b sit 0.10 from it, c 0.04; steady's is 0.02
    assert out.loc["a", "floor_worst"] == pytest.approx(0.10)
    assert out.loc["c", "floor_worst"] == pytest.approx(0.04)
    assert out.loc["b", "replay_worst"] == pytest.approx(0.10)
    assert out.loc["c", "replay_median"] == pytest.approx(0.03)


def test_label_names_a_main_jobs_runs_by_its_job():
    assert rr.label(Path("data/lavapipe/main_job_x/runs")) == "main_job_x"
    assert rr.label(Path("data/nvidia/h200_x4/runs_repeat")) == "runs_repeat"


def test_two_committed_sets_of_4x_h200_runs(tmp_path, capsys):
    """The light sort-first frame on 4 H200s misses in both sets by about as much: a miss of
    the model, not of the runs' repeatability."""
    data = ROOT / "data" / "nvidia" / "h200_x4"
    assert rr.main([str(ROOT / "experiments" / "h200_x4" / "study.toml"), str(data / "runs"),
                    str(data / "runs_repeat_2026-11-27"), "--profile",
                    str(ROOT / "hardware_profiles" / "h200_x4.toml"), "--only", "^cal_sf4_|^sf4_8k",
                    "--out", str(tmp_path)]) == 0
    errors = pd.read_csv(tmp_path / "replay_errors.csv")
    assert sorted(errors.set.unique()) == ["h200_x4", "runs_repeat_2026-11-27"]
    light = errors[errors.config == "cal_sf4_1440p_it1000"].replay
    assert (light < -0.10).all() and light.max() - light.min() < 0.05
    assert "floor_worst" in capsys.readouterr().out


def test_a_set_without_its_own_profile_needs_one(tmp_path):
    with pytest.raises(SystemExit, match="give --profile"):
        rr.set_profile(tmp_path / "runs", None)
