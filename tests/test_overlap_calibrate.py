"""Overlap efficiencies from `mgpusim measure --pass overlap` tables into a profile."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.calibration.overlap_fit import fit_overlap
from mgpusim.calibration.pass_fit import read_measurements
from mgpusim.cli import main
from mgpusim.model.costs import overlap_efficiency
from mgpusim.model.errors import InputError
from mgpusim.model.profile import load_profile

ROOT = Path(__file__).resolve().parents[1]


def _row(pair: str, rep: int, a: int, b: int, together: int, qa: str, qb: str, missing: str = "",
         **size) -> dict:
    return {"device": "NVIDIA H100", "gpu": "gpu0", "gpus": 1, "pass": "overlap", "pair": pair,
            "width": size.get("width", 1920), "height": 1080, "iterations": 1000,
            "particles": 1 << 20, "bytes": 1 << 26, "copy": "h2d", "repetition": rep,
            "queue_a": qa, "queue_b": qb, "missing": missing, "alone_a_ns": a, "alone_b_ns": b,
            "duration_ns": together, "efficiency": overlap_efficiency(a, b, together)}


def _table() -> pd.DataFrame:
    g, c, x = "gpu0.graphics", "gpu0.compute", "gpu0.transfer"
    return pd.DataFrame([
        # equal pieces: (a + b) / together; the fastest of each column counts (rep 1 is disturbed)
        _row("graphics_compute", 0, 1000, 1000, 1600, g, c),
        _row("graphics_compute", 1, 1300, 1000, 2000, g, c),
        # unequal pieces: 2 min / (together - |a - b|) = 2000 / (1500 - 500) = 2 -> each at full
        # speed while both ran
        _row("graphics_transfer", 0, 1500, 1000, 1500, g, x),
        # a second size of graphics_compute: 4000 / 2500 = 1.6; median with 1.25 -> 1.425
        _row("graphics_compute", 0, 2000, 2000, 2500, g, c, width=3840),
        # a family the device lacks: one queue, back to back: says nothing
        _row("compute_transfer", 0, 1000, 1000, 2000, g, g, "no compute family: ran on graphics"),
    ])


def test_fastest_of_and_median_over_sizes():
    fitted, warnings = fit_overlap(_table())
    assert fitted["graphics_compute"][0] == pytest.approx((1.25 + 1.6) / 2)
    assert sorted(fitted["graphics_compute"][1]) == pytest.approx([1.25, 1.6])
    assert fitted["graphics_transfer"][0] == pytest.approx(2.0)
    assert "compute_transfer" not in fitted
    assert any("compute_transfer" in w and "no compute family" in w for w in warnings)


def test_inverse_of_the_models_rule():
    # the model: both at e/2 until the shorter ends, then the rest alone
    a, b, e = 320, 1000, 1.5
    together = 2 * a / e + (b - a)
    assert overlap_efficiency(a, b, together) == pytest.approx(e)
    assert overlap_efficiency(1000, 1000, 2000) == pytest.approx(1.0)
    assert overlap_efficiency(1000, 1000, 900) == 2.0  # faster than perfect: kept at 2


def test_calibrate_writes_queue_overlap_into_a_real_gpus_profile(tmp_path, capsys):
    table = tmp_path / "overlap.csv"
    _table().to_csv(table, index=False)
    out = tmp_path / "p.toml"
    assert main(["calibrate", str(table), "--base", str(ROOT / "hardware_profiles/h100.toml"),
                 "--out", str(out)]) == 0
    assert "queue_overlap: graphics_compute=1.425" in capsys.readouterr().out
    prof = load_profile(out)
    assert prof.gpus[0].overlap("graphics_compute") == pytest.approx(1.425)
    assert prof.gpus[0].overlap("graphics_transfer") == 2.0
    assert "compute_transfer" not in prof.gpus[0].queue_overlap  # left at its default
    # a lavapipe machine: the host's cores are what its GPUs share; nothing written, said why
    lava = tmp_path / "lava.toml"
    assert main(["calibrate", str(table), "--out", str(lava)]) == 0
    assert "not written" in capsys.readouterr().out
    assert not load_profile(lava).gpus[0].queue_overlap


def test_another_graphics_work_gets_a_table_of_its_own(tmp_path):
    g, x = "gpu0.graphics", "gpu0.transfer"
    draw = [dict(_row("graphics_transfer", 0, 1000, 1000, 1250, g, x), graphics="particle_render"),
            dict(_row("compute_transfer", 0, 1000, 1000, 1100, "gpu0.compute", x), graphics="particle_render")]
    df = pd.concat([_table().assign(graphics="fragment_loop"), pd.DataFrame(draw)], ignore_index=True)
    fitted, _ = fit_overlap(df)
    assert fitted["particle_render.graphics_transfer"][0] == pytest.approx(1.6)
    assert fitted["graphics_transfer"][0] == pytest.approx(2.0)  # the fragment loop's, unchanged
    assert fitted["compute_transfer"][0] == pytest.approx(2000 / 1100)  # no graphics work in it
    table = tmp_path / "overlap.csv"
    df.to_csv(table, index=False)
    out = tmp_path / "p.toml"
    assert main(["calibrate", str(table), "--base", str(ROOT / "hardware_profiles/h100.toml"),
                 "--out", str(out)]) == 0
    gpu = load_profile(out).gpus[0]
    assert gpu.overlap("graphics_transfer", ("particle_render", "copy")) == pytest.approx(1.6)
    assert gpu.overlap("graphics_transfer", ("fragment_loop", "copy")) == pytest.approx(2.0)


def test_overlap_rows_need_positive_alone_times(tmp_path):
    df = _table()
    df.loc[0, "alone_a_ns"] = 0
    table = tmp_path / "bad.csv"
    df.to_csv(table, index=False)
    with pytest.raises(InputError, match="alone_a_ns"):
        read_measurements([table])
