"""Runs that say when they are short (mgpusim/results/settled.py): the rule on hand-made frame
arrays, then `simulate` (summary.json and a printed note), `sweep` (a column, the same on the
analytic lanes as point by point) and `advise` (a note)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import mgpusim
from mgpusim.advise.advisor import settle_notes
from mgpusim.cli import main
from mgpusim.results.settled import settling, settling_arrays

ROOT = Path(__file__).resolve().parents[1]
SORT_FIRST = str(ROOT / "experiments" / "sort_first_tc1.toml")
MS = 1_000_000


def frames(periods_ms: list[float], latency_ms: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """(start, present) ns of frames presenting after `periods_ms`, each `latency_ms` long."""
    present = (np.cumsum(periods_ms) * MS).astype(np.int64)
    return present - (np.array(latency_ms) * MS).astype(np.int64), present


def test_a_steady_run_has_settled():
    s = settling(*frames([5.0] * 100, [9.0] * 100), 10)
    assert s["frame_time_settled"] and s["latency_settled"] and s["note"] == ""
    assert s["tail_frames"] == 22 and s["latency_tail_ms"] == pytest.approx(9.0)


def test_a_latency_still_rising_has_not():
    s = settling(*frames([5.0] * 60, list(np.linspace(6.0, 12.0, 60))), 10)
    assert s["frame_time_settled"] and not s["latency_settled"]
    assert "latency still rising over the last 12 frames" in s["note"] and "schedule.frames" in s["note"]


def test_a_pattern_of_two_frames_is_steady():
    """AFR on two GPUs presents in pairs: a short period then a long one; a last quarter of
    an odd number of periods is judged on its pairs' means (a plain mean would be 4 % off)."""
    s = settling(*frames([0.5, 9.5] * 50, [12.0] * 100), 11)  # 88 periods averaged: 5.0 ms
    assert s["tail_frames"] == 22 and s["frame_time_settled"] and s["latency_settled"]
    s = settling(*frames([0.5, 9.5] * 50, [12.0] * 100), 7)  # 23 in the last quarter
    assert s["tail_frames"] == 23 and s["frame_time_settled"]
    assert s["frame_time_tail_ms"] == pytest.approx(5.0, rel=1e-3)


def test_a_flat_end_whose_mean_the_ramp_still_pulls_has_not_settled():
    latency = list(np.linspace(6.0, 12.0, 40)) + [12.0] * 60
    s = settling(*frames([5.0] * 100, latency), 0)
    assert not s["latency_settled"]
    assert "latency settles at 12.000 ms over the last 25 frames, but the" in s["note"]


def test_too_few_frames_cannot_tell():
    s = settling(*frames([5.0] * 12, [9.0] * 12), 2)
    assert not s["frame_time_settled"] and "too few to tell" in s["note"]


def test_many_lanes_give_what_each_lane_gives_alone():
    runs = [frames([5.0] * 60, [9.0] * 60), frames([5.0] * 60, list(np.linspace(6.0, 12.0, 60))),
            frames([0.5, 9.5] * 30, [12.0] * 60)]
    start = np.stack([r[0] for r in runs], axis=1)
    present = np.stack([r[1] for r in runs], axis=1)
    lanes = settling_arrays(start, present, 10)
    for i, run in enumerate(runs):
        alone = settling(*run, 10)
        assert {k: (v[i].item() if isinstance(v[i], np.generic) else v[i]) for k, v in lanes.items()} == \
            pytest.approx(alone, nan_ok=True)


def test_one_run_is_its_lane_bit_for_bit():
    """settling() computes one run on its own arrays: the same values, to the bit, and the same
    types as the lanes give (a sweep's lane is checked against its point's summary)."""
    rng = np.random.default_rng(7)
    for n in [5, 17, 18, 60, 61, 130, 1001]:
        for periods in (rng.integers(10**6, 2 * 10**7, n), 6_378_567 + (np.arange(n) % 3) * 997,
                        6_378_567 + np.arange(n) * 3):
            present = np.cumsum(periods)
            start = present - rng.integers(10**5, 3 * 10**7, n)
            for warmup in (0, 1, 10):
                lanes = settling_arrays(start.reshape(-1, 1), present.reshape(-1, 1), warmup)
                lane = {k: (None if isinstance(v[0], float) and v[0] != v[0] else
                            v[0].item() if isinstance(v[0], np.generic) else v[0]) for k, v in lanes.items()}
                alone = settling(start, present, warmup)
                assert alone == lane
                assert [type(v) for v in alone.values()] == [type(v) for v in lane.values()]


def test_simulate_says_when_the_latency_has_not_settled(tmp_path: Path, capsys):
    """The README's example: 60 frames of sort_first_tc1 report 9.0 ms of latency, still
    rising; the run settles at 12.8 ms from frame 92."""
    out = tmp_path / "short"
    assert main(["simulate", SORT_FIRST, "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settled"] is False and summary["settling"]["latency_settled"] is False
    assert summary["settling"]["frame_time_settled"] is True
    assert summary["latency_ms"] == pytest.approx(9.0, abs=0.05)
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("  note: not settled")]
    assert len(notes) == 1 and "latency still rising" in notes[0]


def test_a_long_run_has_settled(tmp_path: Path, capsys):
    out = tmp_path / "long"
    assert main(["simulate", SORT_FIRST, "--set", "schedule.frames=2000", "--out", str(out),
                 "--no-progress", "--trace-frames", "10"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settled"] is True and summary["settling"]["note"] == ""
    assert summary["settling"]["latency_tail_ms"] == pytest.approx(12.757, abs=0.01)
    assert "not settled" not in capsys.readouterr().out


def test_a_sweep_has_the_column_on_lanes_and_point_by_point(tmp_path: Path, capsys, monkeypatch):
    grid = {"schedule.frames": [60, 2000], "profile.gpus.*.speed": [1.0, 1.5]}
    lanes = mgpusim.sweep(SORT_FIRST, grid, tmp_path / "lanes", fidelity="analytic", workers=1, progress=False)
    monkeypatch.setenv("MGPUSIM_SWEEP_NO_LANES", "1")
    points = mgpusim.sweep(SORT_FIRST, grid, tmp_path / "points", fidelity="analytic", workers=1, progress=False)
    cols = ["settled", "settling.latency_settled", "settling.frame_time_settled", "settling.note"]
    assert lanes[cols].equals(points[cols])
    assert lanes["settled"].tolist() == [False, False, True, True]
    assert lanes["settling.latency_tail_ms"].to_numpy() == pytest.approx(points["settling.latency_tail_ms"].to_numpy())
    capsys.readouterr()
    assert main(["sweep", SORT_FIRST, "--grid", "schedule.gpus=1,2", "--out", str(tmp_path / "cli"),
                 "--workers", "1", "--no-progress"]) == 0
    assert "had not settled by the end of their run (column `settled`" in capsys.readouterr().out
    assert "settled" in pd.read_parquet(tmp_path / "cli" / "sweep.parquet")


def test_advise_notes_options_that_had_not_settled():
    table = pd.DataFrame({"label": ["one GPU", "AFR x2", "sort-first x2"], "confirmed": [True, True, False],
                          "settled": [True, False, False]})
    notes = settle_notes(table)
    assert len(notes) == 1 and notes[0].startswith("1 of the 2 confirmed options had not settled")
    assert "(AFR x2)" in notes[0] and "schedule.frames" in notes[0]
    assert settle_notes(table.assign(settled=True)) == []


def test_advise_prints_and_keeps_the_note(tmp_path: Path, capsys):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n"
                   "gbuffer,graphics,3.0,,gb,16588800,0.6\nlight,graphics,2.0,gb,hdr,16588800,1\n")
    frame = tmp_path / "f.toml"
    assert main(["frame", "import", str(csv), "--size", "1920x1080", "--profile",
                 str(ROOT / "hardware_profiles" / "pcie4_pair.toml"), "--out", str(frame)]) == 0
    out = tmp_path / "advice"
    assert main(["advise", str(frame), "--set", "schedule.frames=12", "--max-gpus", "2", "--confirm", "2",
                 "--timelines", "0", "--workers", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "confirmed options had not settled by the end of their run" in printed
    assert any("had not settled" in n for n in json.loads((out / "advice.json").read_text())["notes"])
    assert "settled" in pd.read_csv(out / "advice.csv")
