"""One-point groups built as one traced program (mgpusim/sweeps/shared_build.py, traced.py):
the sweep's table must be the one every point built by itself gives, value for value and
type for type, over scene and schedule keys on every shipped experiment."""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from mgpusim.model.errors import MgpusimError
from mgpusim.sweeps import shared_build
from mgpusim.sweeps import traced as T
from mgpusim.sweeps.grid import sweep
from mgpusim.sweeps.loader import ExperimentLoader

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "experiments").rglob("*.toml"))


def _both(monkeypatch, experiment, grid, **kw):
    traced = sweep(ROOT / experiment, grid, None, fidelity="analytic", workers=1, progress=False, **kw)
    monkeypatch.setenv("MGPUSIM_SWEEP_NO_TRACE", "1")
    alone = sweep(ROOT / experiment, grid, None, fidelity="analytic", workers=1, progress=False, **kw)
    monkeypatch.delenv("MGPUSIM_SWEEP_NO_TRACE")
    return traced.drop(columns="wall_s"), alone.drop(columns="wall_s")


def _grid(experiment):
    """Widths x heights around the experiment's own (and its GPU count, 1 to its own)."""
    exp = ExperimentLoader(ROOT / experiment).load({})
    w, h = exp.scene.width, exp.scene.height
    grid = {"scene.width": sorted({max(1, w + d) for d in (-64, -1, 0, 7, 320)}),
            "scene.height": sorted({max(1, h + d) for d in (-48, 0, 5)})}
    return grid, exp.schedule.gpus


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_scene_keys_as_built_alone(monkeypatch, experiment):
    try:
        grid, gpus = _grid(experiment)
    except MgpusimError:
        pytest.skip("does not load")
    if gpus > 1:
        grid["schedule.gpus"] = [1, gpus] if gpus > 2 else [gpus - 1, gpus]
    traced, alone = _both(monkeypatch, experiment, grid)
    assert list(traced.columns) == list(alone.columns)
    assert (traced.dtypes == alone.dtypes).all()
    pd.testing.assert_frame_equal(traced, alone, check_exact=True)


def test_traced_sets_are_built(monkeypatch):
    """The grid of the benchmark's `scene` (smaller): its points share a few traced builds."""
    loader = ExperimentLoader(ROOT / "experiments/sort_first_tc1.toml")
    from mgpusim.sweeps import lanes
    from mgpusim.sweeps.grid import grid_points
    grid = {"scene.width": [600 + 8 * i for i in range(10)], "scene.height": [400 + 6 * i for i in range(8)]}
    plan = lanes.plan(loader.path, grid, {}, loader)
    groups = lanes.groups(plan, grid_points(grid, {}), grid)
    sets, left = shared_build.traced_sets(groups, loader.path, {}, "analytic", loader, {}, lanes.build,
                                             lanes._static_fields)
    assert sets and not left
    assert sum(len(s.groups) for s in sets) == 80


def test_values_and_branches():
    x = T.Traced([1, 2, 3], frozenset(["w"]))
    y = x * 2 + 1
    assert y.v == [3, 5, 7]
    assert (x * 0) == 0 and type(x * 0) is int  # the same at every point: a plain value
    assert isinstance(x, int) and not isinstance(x, float)
    assert (x > 0) is True
    with pytest.raises(T.Split) as split:
        bool(x > 1)
    assert split.value.answers == [False, True, True]
    for use in (int, float, hash, str, range, len, lambda v: v.real, lambda v: f"{v}", lambda v: [0][v]):
        with pytest.raises(T.Untraceable):
            use(x)
    assert (x / 2).v == [0.5, 1.0, 1.5]
    assert math.floor(x / 2).v == [0, 1, 1]
    assert round(x / 3, 2).v == [0.33, 0.67, 1.0]
    assert divmod(x, 2)[1].v == [1, 0, 1]


def test_conversions_restore_the_modules():
    import mgpusim.model.costs as costs
    x = T.Traced([1, 2], frozenset(["w"]))
    with T.conversions():
        assert costs.__dict__["float"](x).v == [1.0, 2.0]
        assert isinstance(1.5, costs.__dict__["float"])
    assert "float" not in costs.__dict__ and "int" not in costs.__dict__


def test_differences():
    exp = ExperimentLoader(ROOT / "experiments/sort_first_tc1.toml")
    a, b = exp.load({}), exp.load({"scene.width": 800})
    assert shared_build.experiment_differences(a, b) == {("scene", "width"): 800}
    c = exp.load({"profile.host.memcpy_thread_gbps": 7})
    assert shared_build.experiment_differences(a, c) is None
