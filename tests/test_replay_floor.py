"""mgpusim study floor (mgpusim/studies/floor.py): the floor runs put under the replay."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.studies import floor as rf

ROOT = Path(__file__).resolve().parents[1]
H200_X4 = ROOT / "data" / "nvidia" / "h200_x4"


def _errors() -> pd.DataFrame:
    """Two configurations over three sets: `steady` moves by 0.02 in all, `noisy` by 0.20."""
    rows = [("a", "steady", 0.01), ("b", "steady", 0.03), ("c", "steady", 0.02),
            ("a", "noisy", -0.10), ("b", "noisy", 0.10), ("c", "noisy", 0.04),
            ("a", "one_set_only", 0.5)]
    return pd.DataFrame([{"set": s, "half": "held out", "config": c, "replay": e, "prediction": 0.0}
                         for s, c, e in rows])


def test_spread_is_half_the_range_over_the_sets_seen_in_all():
    table = rf.spread(_errors())
    assert list(table.index.get_level_values("config")) == ["steady", "noisy"]  # the one-set config dropped
    assert table.loc[("held out", "noisy"), "half_range"] == pytest.approx(0.10)
    assert table.loc[("held out", "steady"), "half_range"] == pytest.approx(0.01)


def test_floor_measures_each_set_from_the_configurations_mid_range():
    out = rf.floor(rf.spread(_errors()))
    # noisy's mid-range is 0: sets a and b sit 0.10 from it, c 0.04; steady's is 0.02
    assert out.loc["a", "floor_worst"] == pytest.approx(0.10)
    assert out.loc["c", "floor_worst"] == pytest.approx(0.04)
    assert out.loc["b", "replay_worst"] == pytest.approx(0.10)
    assert out.loc["c", "replay_median"] == pytest.approx(0.03)


def test_sets_are_named_by_their_folder_or_path():
    assert rf.set_names([Path("data/lavapipe/job_a/runs"), Path("data/x/runs_repeat")]) == ["job_a", "runs_repeat"]
    same = [Path("one/h200/runs"), Path("two/h200/runs")]
    assert rf.set_names(same) == [str(p) for p in same]


def test_a_set_without_its_own_profile_needs_one(tmp_path):
    with pytest.raises(InputError, match="give --profile"):
        rf.set_profile(tmp_path / "runs", None)
    assert rf.set_profile(tmp_path / "runs", Path("p.toml")) == Path("p.toml")


def test_two_committed_sets_of_4x_h200_runs(tmp_path, capsys):
    """On the Python executor's runs the light sort-first frame on 4 H200s misses in both sets
    by about as much: a miss of the model (or the runner), not of the runs' repeatability."""
    out = tmp_path / "floor"
    assert main(["study", "floor", str(ROOT / "experiments" / "h200_x4" / "study.toml"),
                 "--runs", str(H200_X4 / "runs"), "--runs", str(H200_X4 / "runs_repeat_2026-11-27"),
                 "--profile", str(ROOT / "hardware_profiles" / "h200_x4.toml"),
                 "--only", "^cal_sf4_|^sf4_8k", "--out", str(out)]) == 0
    errors = pd.read_csv(out / "replay_errors.csv")
    assert sorted(errors.set.unique()) == ["h200_x4", "runs_repeat_2026-11-27"]
    light = errors[errors.config == "cal_sf4_1440p_it1000"].replay
    assert (light < -0.10).all() and light.max() - light.min() < 0.05
    per_set = pd.read_csv(out / "replay_floor_per_set.csv", index_col=0)
    assert (per_set.floor_worst < 0.03).all() and (per_set.replay_worst > 0.10).all()
    assert "floor_worst" in capsys.readouterr().out


def test_one_set_is_refused_before_any_work(tmp_path, capsys):
    assert main(["study", "floor", str(ROOT / "experiments" / "h200_x4" / "study.toml"),
                 "--runs", str(H200_X4 / "runs"), "--out", str(tmp_path / "f")]) != 0
    assert "two or more --runs" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


def test_a_missing_runs_folder_is_named(tmp_path, capsys):
    assert main(["study", "floor", str(ROOT / "experiments" / "h200_x4" / "study.toml"),
                 "--runs", str(H200_X4 / "runs"), "--runs", str(tmp_path / "nowhere"),
                 "--profile", str(ROOT / "hardware_profiles" / "h200_x4.toml"), "--out", str(tmp_path / "f")]) != 0
    assert "nowhere" in capsys.readouterr().err


def test_two_committed_sets_of_the_native_cores_4x_h200_runs(tmp_path):
    """On the native core's runs the same frame replays within 3 % in both sets, and no
    configuration's replay moves by more than 1 % between them."""
    out = tmp_path / "floor"
    assert main(["study", "floor", str(ROOT / "experiments" / "h200_x4" / "study.toml"),
                 "--runs", str(H200_X4 / "runs_native_2026-11-27"),
                 "--runs", str(H200_X4 / "runs_native_repeat_2026-11-27"),
                 "--profile", str(ROOT / "hardware_profiles" / "h200_x4.toml"),
                 "--only", "^cal_sf4_|^sf4_|^xrs4_", "--out", str(out)]) == 0
    errors = pd.read_csv(out / "replay_errors.csv")
    light = errors[errors.config == "cal_sf4_1440p_it1000"].replay
    assert len(light) == 2 and (light.abs() < 0.03).all()
    per_set = pd.read_csv(out / "replay_floor_per_set.csv", index_col=0)
    assert (per_set.floor_worst < 0.01).all() and (per_set.replay_worst < 0.03).all()
