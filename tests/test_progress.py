"""Progress for long commands, and the note a lower fidelity level leaves on the console."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.cli import main
from mgpusim.io.progress import bar, reporter
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("fidelity,fast_forward", [("full", False), ("full", True), ("analytic", True)])
def test_simulate_reports_frames_done_up_to_the_frames_it_simulates(fidelity, fast_forward):
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.frames": 2000})
    calls: list[tuple[int, int]] = []
    result = simulate(exp, fidelity=fidelity, fast_forward=fast_forward,
                      progress=lambda done, total: calls.append((done, total)))
    assert (2 if result.summary["fast_forward"]["used"] else 50) <= len(calls) <= 1000
    done = [d for d, _ in calls]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1]
    skipped = result.summary["fast_forward"].get("frames_skipped", 0)
    if fidelity == "full":
        assert calls[-1][1] == 2000 - skipped  # a fast-forward shortens what is left to simulate
    assert result.summary == simulate(exp, fidelity=fidelity, fast_forward=fast_forward).summary


def test_a_bar_follows_a_total_that_shrinks():
    with bar(100, "x") as shown:  # drawn after a second only: nothing here
        report = reporter(shown)
        report(10, 100)
        report(30, 40)
        assert (shown.n, shown.total) == (30, 40)


def test_a_level_that_leaves_needed_effects_out_says_so(tmp_path: Path, capsys):
    assert main(["simulate", "lavapipe/pipelining", "--fidelity", "analytic", "--no-progress",
                 "--out", str(tmp_path / "a")]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if "note:" in line]
    assert len(notes) == 1 and "left out busy_wake, shared_executor" in notes[0]
    assert main(["simulate", "lavapipe/pipelining", "--fidelity", "analytic", "--effects", "-busy_wake",
                 "--no-progress", "--out", str(tmp_path / "b")]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if "note:" in line]
    assert len(notes) == 1 and "left out shared_executor," in notes[0]  # the one forced off is no news
    assert main(["simulate", "lavapipe/pipelining", "--no-progress", "--out", str(tmp_path / "c")]) == 0
    captured = capsys.readouterr()
    # full leaves nothing out (its 24 frames are too short to settle: that note is another's);
    # no bar asked for (on a loaded machine the run can pass the second after which one shows)
    assert "left out" not in captured.out and captured.err == ""
