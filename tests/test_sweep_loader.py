"""The sweep's experiment loader (parsed once, overridden in memory) against load_experiment:
equal experiments, or the same error, over every shipped experiment and many overrides, valid
and not; the profile parsed once per distinct set of profile overrides."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.model.errors import InputError
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sweeps.loader import ExperimentLoader

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = [p for p in sorted((ROOT / "experiments").rglob("*.toml")) if "[schedule]" in p.read_text()]

OVERRIDES = [
    {}, {"scene.width": 1280}, {"scene.width": 1280.0}, {"scene.width": "wide"}, {"scene.width": -3},
    {"schedule.gpus": 2}, {"schedule.gpus": 99}, {"schedule.frames": 30, "schedule.warmup_frames": 5},
    {"profile.gpus.*.speed": 2.0}, {"profile.gpus.*.speed": 2}, {"profile.gpus.0.speed": -1.0},
    {"profile.host.memcpy_threads": 3}, {"profile.bogus": 1}, {"scene.bogus": 1}, {"bogus": 1},
    {"profile.gpu_count": 4, "schedule.gpus": 4}, {"scene.passes.0.bogus": 2},
    {"profile.gpus.*.link.pcie_gen": 5, "scene.height": 600}, {"name": "other"}, {"profile": "nope.toml"},
]


def _outcome(fn):
    try:
        return fn()
    except InputError as exc:
        return ("error", str(exc))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: str(p.relative_to(ROOT / "experiments")))
def test_the_loader_gives_load_experiments_result(path):
    loader = ExperimentLoader(path)
    for overrides in OVERRIDES * 2:  # the second time from the loader's caches
        want = _outcome(lambda o=overrides: load_experiment(path, o))
        got = _outcome(lambda o=overrides: loader.load(o))
        assert got == want, overrides


def test_each_profile_is_parsed_once(monkeypatch):
    from mgpusim.sweeps import loader as loader_mod

    calls = []
    real = loader_mod.parse_profile
    monkeypatch.setattr(loader_mod, "parse_profile", lambda *a: calls.append(a) or real(*a))
    loader = ExperimentLoader(ROOT / "experiments" / "sort_first_tc1.toml")
    for width in (800, 900, 1000):
        for speed in (1.0, 2.0):
            assert loader.load({"scene.width": width, "profile.gpus.*.speed": speed}).scene.width == width
    assert len(calls) == 2
    with pytest.raises(InputError):
        loader.load({"profile.gpus.0.speed": -1.0})
    with pytest.raises(InputError):
        loader.load({"profile.gpus.0.speed": -1.0})
    assert len(calls) == 3  # a profile that fails is not parsed again


def test_a_missing_experiment_file_is_the_same_error(tmp_path):
    path = tmp_path / "none.toml"
    assert _outcome(lambda: ExperimentLoader(path).load({})) == _outcome(lambda: load_experiment(path))


def test_each_scene_and_schedule_table_is_parsed_once_per_set_of_its_overrides(monkeypatch):
    from mgpusim.sweeps import loader as loader_mod

    scenes, schedules = [], []
    scene, schedule = loader_mod.parse_scene, loader_mod.parse_schedule_config
    monkeypatch.setattr(loader_mod, "parse_scene", lambda *a: scenes.append(a) or scene(*a))
    monkeypatch.setattr(loader_mod, "parse_schedule_config", lambda *a: schedules.append(a) or schedule(*a))
    path = ROOT / "experiments" / "sort_first_tc1.toml"
    loader = ExperimentLoader(path)
    for width in (800, 900):
        for gpus in (1, 2, 3):
            exp = loader.load({"scene.width": width, "schedule.gpus": gpus, "profile.gpus.*.speed": 2.0})
            assert exp == load_experiment(path, {"scene.width": width, "schedule.gpus": gpus,
                                                 "profile.gpus.*.speed": 2.0})
    assert len(scenes) == 2 and len(schedules) == 3
    for _ in range(2):  # a table that fails to parse fails again with the same error, unparsed
        with pytest.raises(InputError, match="scene.width"):
            loader.load({"scene.width": -3})
    assert len(scenes) == 3
