"""The replay level: the model's timeline on a run's own task durations.

A simulated run replayed on its own durations must come back start for start (the timeline is
the same model); a measured run's queue fallbacks are modelled as they ran; a timeline that
differs from the run's (here: a host hand-off the replay lacks) shows as a replay error."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_experiment
from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.model.tasks import QueueRef
from mgpusim.schedules.program import build_program, on_queues
from mgpusim.sim.replay import replay
from mgpusim.sim.simulation import simulate
from mgpusim.studies.measuring import measured_folder
from mgpusim.studies.study_file import load_study
from mgpusim.validation.measured import queues_as_run
from mgpusim.validation.replayed import measured_durations, replay_comparison

ROOT = Path(__file__).resolve().parents[1]
EXP = ROOT / "experiments"


def _times(trace: pd.DataFrame) -> pd.DataFrame:
    keys = ["frame", "task", "device", "engine", "start_ns"]
    return trace.sort_values(keys).reset_index(drop=True)[keys + ["end_ns"]]


@pytest.mark.parametrize("name", ["sort_last_tc1.toml", "afr_temporal_tc1.toml", "h100_x2/xr.toml",
                                  "h100_x2/particles.toml", "pipelining_miniengine_pcie3x8.toml"])
def test_a_simulated_run_replays_start_for_start(name):
    """Link sharing, host copies over memcpy threads, host submission, skipped particle updates:
    given the durations the model itself produced, the replay puts every task where the model did."""
    exp = load_experiment(EXP / name, {"schedule.frames": 40})
    sim = simulate(exp, fast_forward=False)
    durations, frames = measured_durations(sim.trace)
    replayed = replay(exp, durations, frames)
    pd.testing.assert_frame_equal(_times(replayed.trace), _times(sim.trace), check_dtype=False)
    assert replayed.summary["fidelity"] == "replay"


@pytest.mark.parametrize("name", ["sort_first.toml", "pipelining.toml", "afr_temporal.toml"])
def test_a_cpu_emulated_run_replays_within_microseconds(name):
    """GPUs emulated on the host's cores: the measured work occupies the cores the host threads
    wake on. Two things differ from the model by design: the submit threads' own work shares the
    cores (in the model it also stretches the passes, in the replay they keep their time), and
    every part of a host copy takes the copy's longest part. Tasks move by well under 1 % of a
    frame, the frame time by under 0.1 %."""
    exp = load_experiment(EXP / "lavapipe" / name, {"schedule.frames": 30})
    sim = simulate(exp, fast_forward=False)
    r = replay(exp, *measured_durations(sim.trace))
    a, b = _times(sim.trace), _times(r.trace)
    assert len(a) == len(b)
    frame_ns = sim.summary["frame_time_ms"] * 1e6
    assert (a["start_ns"] - b["start_ns"]).abs().max() < 0.01 * frame_ns
    assert r.summary["frame_time_ms"] == pytest.approx(sim.summary["frame_time_ms"], rel=1e-3)


def test_a_busy_wake_run_replays_within_a_few_microseconds():
    """busy_wake sizes a copy's wait by the pass's remaining work, which the replay reckons
    from the pass's measured (shared) time rather than its cost alone: a few tasks move by
    microseconds, the frame time does not."""
    exp = load_experiment(EXP / "lavapipe" / "sort_last.toml", {"schedule.frames": 40})
    sim = simulate(exp, fast_forward=False)
    r = replay(exp, *measured_durations(sim.trace))
    assert r.summary["frame_time_ms"] == pytest.approx(sim.summary["frame_time_ms"], rel=1e-3)
    assert "shared_executor" not in r.summary["modelled_effects"]
    assert "busy_wake" in r.summary["modelled_effects"]


def test_a_missing_hand_off_shows_as_a_replay_error():
    """'Measured' with a 0.5 ms host dispatch before every cross-device task, replayed on a
    profile without it: the durations are the same, the timeline is not, and the replay says so."""
    exp = load_experiment(EXP / "afr_temporal_tc1.toml", {"schedule.frames": 40})
    slow_host = replace(exp.profile, host=replace(exp.profile.host, dispatch_ns=500_000))
    measured = simulate(replace(exp, profile=slow_host), fast_forward=False).trace
    report, _ = replay_comparison(exp, measured)
    assert report["frame_time_error"] < -0.05 and report["latency_error"] < -0.05
    same, _ = replay_comparison(replace(exp, profile=slow_host), measured)
    assert same["frame_time_error"] == pytest.approx(0.0, abs=1e-12)


def test_a_task_the_run_skipped_takes_its_median():
    exp = load_experiment(EXP / "afr_tc1.toml", {"schedule.frames": 20})
    sim = simulate(exp, fast_forward=False)
    durations, frames = measured_durations(sim.trace)
    present = next(k for k in durations if k[1] == "present" and k[0] == 10)
    del durations[present]
    r = replay(exp, durations, frames)
    row = r.trace[(r.trace["frame"] == 10) & (r.trace["task"] == "present")].iloc[0]
    others = sorted(v for (f, t), v in durations.items() if t == "present")
    assert row["end_ns"] - row["start_ns"] == others[len(others) // 2]


def test_an_empty_run_is_refused():
    exp = load_experiment(EXP / "afr_tc1.toml")
    with pytest.raises(InputError, match="no frames"):
        replay(exp, {}, 0)


def test_a_second_queue_the_runner_lacked_is_modelled_as_run():
    """AFR presents on GPU 0's second graphics queue; the runner opens one queue per family, so
    its run has the presents on the first. The run's trace says so; the program follows it."""
    exp = load_experiment(EXP / "h100_x2" / "afr.toml", {"schedule.frames": 12})
    program = build_program(exp)
    second, first = QueueRef(0, "graphics", 1), QueueRef(0, "graphics")
    assert any(t.queue == second for t in program.templates[0] if t.name == "present")
    ran = simulate(exp, queues={second: first}).trace
    assert set(ran.loc[ran["task"] == "present", "engine"]) == {"graphics"}
    assert queues_as_run(ran, program) == {second: first}
    assert queues_as_run(simulate(exp).trace, program) == {}
    moved = on_queues(program, {second: first})
    assert [t.name for t in moved.templates[1]] == [t.name for t in program.templates[1]]


def test_validate_reports_both_levels(tmp_path):
    """`mgpusim validate` against a committed H100 run: summary.json carries the replay level
    beside the prediction, and the presents are modelled on the queue they ran on."""
    study = load_study(EXP / "h100_x2" / "study.toml")
    entry = next(e for e in study.held_out if e.name == "afr_2gpu_1440p_it2000")
    args = ["validate", str(entry.experiment), "--measured",
            str(measured_folder(study.held_out_runs, entry.name)), "--out", str(tmp_path / "v")]
    for item in entry.sets:
        args += ["--set", item]
    assert main(args) == 0
    summary = json.loads((tmp_path / "v" / "summary.json").read_text())
    assert abs(summary["replay_frame_time_error"]) < 0.05
    assert summary["replay"]["frame_time_error"] == summary["replay_frame_time_error"]
    assert summary["queues_as_run"] == {"gpu0.graphics#1": "gpu0.graphics"}
    assert (tmp_path / "v" / "replayed_trace.parquet").is_file()


def test_an_update_the_run_skipped_is_skipped_in_the_replay():
    """The replay skips a skippable task exactly where the run did, not by the model's rule: a
    run whose every other particle update is missing replays with those updates skipped."""
    exp = load_experiment(EXP / "h100_x2" / "particles.toml",
                          {"schedule.frames": 30, "schedule.gpus": 1, "schedule.particle_gpu": 0})
    sim = simulate(exp, fast_forward=False)
    durations, frames = measured_durations(sim.trace)
    ran = {f for (f, t) in durations if t == "particle_update"}
    assert len(ran) == frames  # the model updates every frame here
    for f in range(1, frames, 2):
        del durations[(f, "particle_update")]
    r = replay(exp, durations, frames)
    updated = set(r.trace.loc[r.trace["task"] == "particle_update", "frame"])
    assert updated == set(range(0, frames, 2))
