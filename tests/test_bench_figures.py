"""`mgpusim bench --what figures --json`: every figure a user feels, each with its ratio to the
reference loop. The shape only (keys and types), never the times: the machine is shared."""
from __future__ import annotations

import json
import numbers

import pytest

from mgpusim.bench import figures as figs
from mgpusim.cli import main


@pytest.fixture()
def small(monkeypatch):
    """The same figures on small work: two-point sweeps, one start-up run, short AFR runs."""
    for name, (exp, grid, extra) in list(figs.SWEEPS.items()):
        monkeypatch.setitem(figs.SWEEPS, name, (exp, [g.split(",")[0] + "," + g.split(",")[1] for g in grid[:1]], extra))
    monkeypatch.setattr(figs, "AFR_FRAMES", 60)
    startup = figs.startup_s
    monkeypatch.setattr(figs, "startup_s", lambda runs=1: startup(runs))
    call = figs.simulate_call_s
    monkeypatch.setattr(figs, "simulate_call_s", lambda path, repeat=2: call(path, repeat))


def _leaves(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        if isinstance(value, dict) and "reference_ratio" not in value:
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def test_the_json_has_every_figure_with_its_ratio(small, capsys):
    assert main(["bench", "--what", "figures", "--json", "--no-progress"]) == 0
    out = json.loads(capsys.readouterr().out)["figures"]
    assert isinstance(out["reference_loop_s"], float) and out["reference_loop_s"] > 0
    leaves = dict(_leaves({k: v for k, v in out.items() if isinstance(v, dict)}))
    expected = {"sweep.analytic.points_per_s", "sweep.full.points_per_s", "startup.version_s",
                "startup.bare_interpreter_s", *(f"simulate_call.{name}.{level}_{how}"
                                                for name in figs.SORT_FIRST for level in ("analytic", "full")
                                                for how in ("s", "fresh_load_s")),
                *(f"afr_fast_forward.{n}_gpus" for n in figs.AFR_GPUS)}
    assert expected <= set(leaves)
    assert "advise_20_passes.wall_s" not in leaves  # behind --advise
    for name, value in leaves.items():
        if isinstance(value, int):  # a count (points)
            continue
        assert set(value) == {"value", "unit", "reference_ratio"}, name
        assert isinstance(value["value"], numbers.Real) and isinstance(value["reference_ratio"], numbers.Real)
        assert value["unit"] in ("s", "points/s"), name
