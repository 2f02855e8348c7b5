"""The overlap microbenchmark on lavapipe (tiny sizes): pairs of queues alone and at once."""
from __future__ import annotations

import pandas as pd
import pytest

from mgpusim.calibration.overlap_fit import fastest_of, fit_overlap
from mgpusim.cli import main

pytestmark = pytest.mark.vulkan

SMALL = ["--sweep", "width=32", "--sweep", "height=32", "--sweep", "iterations=100",
         "--sweep", "particles=1024", "--sweep", "bytes=64KiB", "--reps", "2", "--warmup", "1"]


def test_overlap_table_says_which_families_are_missing(tmp_path, capsys):
    out = tmp_path / "overlap.csv"
    # five repetitions: the one-queue check below compares medians, as one 0.2 ms repetition
    # alone can come out slower than a pair on a busy machine
    rc = main(["measure", "--pass", "overlap", "--sweep", "pair=graphics_compute,devices", *SMALL,
               "--reps", "5", "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "no compute family: ran on graphics" in printed and "efficiency" in printed
    df = pd.read_csv(out)
    assert len(df) == 2 * 5 and set(df["pass"]) == {"overlap"}
    assert (df.alone_a_ns > 0).all() and (df.alone_b_ns > 0).all()
    assert ((df.efficiency > 0) & (df.efficiency <= 2)).all()
    one = df[df.pair == "graphics_compute"]
    # lavapipe has one queue family: both pieces ran on its one queue, one after the other
    # (their sum, were it not for noise): the pair's median outlasts the slower piece's median
    assert (one.queue_a == one.queue_b).all()
    assert one.duration_ns.median() >= max(one.alone_a_ns.median(), one.alone_b_ns.median())
    two = df[df.pair == "devices"]
    assert (two.queue_a == "gpu0.graphics").all() and (two.queue_b == "gpu1.graphics").all()
    assert (two.gpus == 2).all()
    fitted, warnings = fit_overlap(df)
    assert set(fitted) == {"devices"}  # the one-queue pair says nothing and is left out
    assert any("graphics_compute" in w and "not fitted" in w for w in warnings)
    assert len(fastest_of(df)) == 2


def test_the_graphics_work_can_be_the_particle_draw(tmp_path):
    out = tmp_path / "draw.csv"
    assert main(["measure", "--pass", "overlap", "--sweep", "pair=devices",
                 "--sweep", "graphics=particle_render", *SMALL, "--quiet", "--out", str(out)]) == 0
    df = pd.read_csv(out)
    assert set(df.graphics) == {"particle_render"} and (df.alone_a_ns > 0).all()
    assert set(fit_overlap(df)[0]) == {"particle_render.devices"}
    assert main(["measure", "--pass", "overlap", "--sweep", "graphics=mesh", *SMALL, "--quiet",
                 "--out", str(tmp_path / "bad.csv")]) != 0
