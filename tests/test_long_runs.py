"""Runs longer than 10^6 frames (mgpusim/model/limits.py: MAX_FRAMES, MAX_RECORDED_FRAMES).

`schedule.frames` reads up to 10^7; a run goes past 10^6 frames only once it has
fast-forwarded. A fast-forwarded long run is the shorter run's transient, its repeated
block and its end, exactly; one that does not repeat gets one error naming the field, before
anything is written."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim import InputError, load_experiment, simulate
from mgpusim.cli import main
from mgpusim.model.limits import MAX_FRAMES, MAX_RECORDED_FRAMES
from mgpusim.sim import analytic, fastforward
from mgpusim.sim.engine import Engine

ROOT = Path(__file__).resolve().parents[1]
LONG = 2 * MAX_RECORDED_FRAMES


def _load(name: str, frames: int, **more):
    return load_experiment(ROOT / "experiments" / f"{name}.toml", {"schedule.frames": frames, **more})


@pytest.mark.parametrize(("name", "short"), [("sort_first_tc1", 3000), ("afr_tc1", 3000)])
def test_a_fast_forwarded_run_of_2e6_frames_is_the_shorter_run_repeated(name: str, short: int) -> None:
    """Every frame of the long run is the short run's: its first frames the same, its last
    ones the short run's last shifted by the frames and time between the two ends (both runs
    repeat with the same period and shift, and the long run's length differs by whole periods);
    its summary's frame count, frame time and latency are those frames' exactly."""
    s, g = simulate(_load(name, short)), simulate(_load(name, LONG))
    ff = g.summary["fast_forward"]
    assert ff["used"] and ff == {**s.summary["fast_forward"], "frames_skipped": ff["frames_skipped"]}
    p, t = ff["period_frames"], ff["period_ns"]
    d = LONG - short
    assert d % p == 0 and ff["frames_skipped"] > LONG - 10_000
    sf, gf = s.frames, g.frames
    assert g.summary["frames"] == len(gf) == LONG
    head = 2 * ff["from_frame"] + 100
    pd.testing.assert_frame_equal(gf.iloc[:head], sf.iloc[:head])
    tail = gf.iloc[-head:].reset_index(drop=True)
    moved = sf.iloc[-head:].reset_index(drop=True).assign(
        frame=lambda f: f["frame"] + d, start_ns=lambda f: f["start_ns"] + d // p * t,
        present_ns=lambda f: f["present_ns"] + d // p * t)
    pd.testing.assert_frame_equal(tail, moved)
    # every frame between the two: one period on, one shift later
    present = gf["present_ns"].to_numpy(np.int64)
    assert (present[head + p:-head] - present[head:-head - p] == t).all()
    # the summary's figures: the steady state after the warm-up, from the short run's frames
    w = g.summary["warmup_frames"]
    sp = sf["present_ns"].to_numpy(np.int64)
    assert g.summary["frame_time_ms"] == pytest.approx((sp[-1] + d // p * t - sp[w]) / (LONG - 1 - w) / 1e6,
                                                       rel=1e-12)
    lat = sf["latency_ns"].to_numpy(np.int64)
    steady = lat[short // 2 - short // 2 % p:][:p]  # one period of the repeat's latencies
    total = lat[w:].sum() + int(steady.sum()) * (d // p)
    assert g.summary["latency_ms"] == pytest.approx(total / (LONG - w) / 1e6, rel=1e-12)
    assert g.summary["frame_time_ms"] == pytest.approx(t / p / 1e6, rel=1e-4)  # the repeat's period


def test_the_longest_run_read_is_1e7_frames() -> None:
    assert _load("sort_first_tc1", MAX_FRAMES).schedule.frames == 10 ** 7
    with pytest.raises(InputError, match=r"schedule\.frames: must be <= 1e\+07") as refused:
        _load("sort_first_tc1", MAX_FRAMES + 1)
    assert refused.value.field == "schedule.frames"


def _refused(exc: pytest.ExceptionInfo, frames: int, why: str) -> None:
    e = exc.value
    assert e.field == "schedule.frames"
    text = str(e)
    assert f"{frames:,} frames" in text and f"above {MAX_RECORDED_FRAMES:,} a run must fast-forward" in text
    assert why in text and "keep every frame's records" in text
    assert f"give at most {MAX_RECORDED_FRAMES:,} frames, or a schedule whose state repeats" in text


def test_vmgpu_above_1e6_frames_is_refused_where_the_fast_forward_gives_up() -> None:
    """vmgpu's state does not repeat within the frames the fast-forward looks at (its host
    submit clock falls behind for longer the longer the run): refused there, after 4,000
    frames, not after 10^6. At 10^6 frames it runs (not here: a minute frame by frame)."""
    with pytest.raises(InputError) as exc:
        simulate(_load("vmgpu/vmgpu", MAX_RECORDED_FRAMES + 1), record_trace=False)
    _refused(exc, MAX_RECORDED_FRAMES + 1, f"no repeat within the first {fastforward.PROBE_FRAMES} frames")
    assert exc.value.file.endswith("vmgpu.toml")


def test_without_the_fast_forward_or_with_vsync_a_long_run_is_refused_before_it_starts(
        monkeypatch: pytest.MonkeyPatch) -> None:
    def no_run(self):  # (the run never starts)
        raise AssertionError("ran")
    monkeypatch.setattr(Engine, "run", no_run)
    with pytest.raises(InputError) as exc:
        simulate(_load("sort_first_tc1", LONG), fast_forward=False)
    _refused(exc, LONG, "the fast-forward is off")
    with pytest.raises(InputError) as exc:
        simulate(_load("sort_first_tc1", LONG, **{"schedule.refresh_hz": 60.0}))
    _refused(exc, LONG, "vsync")


def test_the_engine_goes_past_the_bound_only_once_it_has_fast_forwarded(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bound lowered to 100 frames and the fast-forward looking at 30: sort-first TC1
    repeats from frame 92, so a 150-frame run is refused; looking at 200 frames it repeats,
    and runs (as it does at 100 frames, within the bound, without a repeat)."""
    monkeypatch.setattr(fastforward, "MAX_RECORDED_FRAMES", 100)
    monkeypatch.setattr(fastforward, "PROBE_FRAMES", 30)
    with pytest.raises(InputError) as exc:
        simulate(_load("sort_first_tc1", 150))
    assert "no repeat within the first 30 frames" in str(exc.value)
    assert not simulate(_load("sort_first_tc1", 100)).summary["fast_forward"]["used"]
    monkeypatch.setattr(fastforward, "PROBE_FRAMES", 200)
    assert simulate(_load("sort_first_tc1", 150)).summary["fast_forward"]["used"]


def test_the_analytic_level_goes_past_the_bound_only_once_it_has_repeated(monkeypatch: pytest.MonkeyPatch) -> None:
    """The analytic level looks for a repeat at every frame: with the bound at 50 frames, TC1
    sort-last (repeating from frame ~1000) is refused at frame 50, sort-first (from ~94) too,
    and AFR (from ~47) runs. TC1 sort-first's 60 frames are filled in by an affine stretch (no
    state repeats, every frame's rows kept): refused as soon as the stretch shows it."""
    monkeypatch.setattr(analytic, "MAX_RECORDED_FRAMES", 50)
    for name in ("sort_last_tc1", "sort_first_tc1"):
        with pytest.raises(InputError) as exc:
            simulate(_load(name, 2000), fidelity="analytic")
        assert exc.value.field == "schedule.frames" and "no repeat within the first 50 frames" in str(exc.value)
    assert simulate(_load("afr_tc1", 2000), fidelity="analytic").summary["fast_forward"]["used"]
    with pytest.raises(InputError) as exc:
        simulate(_load("sort_first_tc1", 60), fidelity="analytic")
    assert "the state never repeats" in str(exc.value)


def _cli_refused(argv: list[str], out: Path, capsys: pytest.CaptureFixture, *words: str) -> None:
    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not out.exists() and not list(out.parent.glob("*.tmp*"))  # nothing written, nothing half-done


def test_the_cli_writes_a_fast_forwarded_long_run_and_refuses_one_that_does_not_repeat(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "vmgpu"
    _cli_refused(["simulate", str(ROOT / "experiments" / "vmgpu" / "vmgpu.toml"), "--set", f"schedule.frames={MAX_RECORDED_FRAMES + 1}", "--out", str(out),
                  "--no-progress"], out, capsys, "vmgpu.toml: schedule.frames: 1,000,001 frames", "fast-forward")
    out = tmp_path / "off"
    _cli_refused(["simulate", "sort_first_tc1", "--set", f"schedule.frames={LONG}", "--no-fast-forward",
                  "--out", str(out)], out, capsys, "schedule.frames", "the fast-forward is off")
    out = tmp_path / "long"
    assert main(["simulate", "sort_first_tc1", "--set", f"schedule.frames={LONG}", "--out", str(out),
                 "--no-progress", "--frames", f"{LONG - 4}:{LONG}"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == LONG and summary["fast_forward"]["used"]
    assert len(pd.read_parquet(out / "frames.parquet")) == LONG


def test_a_case_above_1e6_frames_that_does_not_repeat_names_its_frames_option(
        tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    """`mgpusim case --frames N` follows the same rule (the bound lowered to 100 frames and the
    fast-forward looking at 20, so that the thesis's sort-first runs, repeating from frame 66,
    do not repeat in time): one error naming --frames and the run."""
    monkeypatch.setattr(fastforward, "MAX_RECORDED_FRAMES", 100)
    monkeypatch.setattr(fastforward, "PROBE_FRAMES", 20)
    out = tmp_path / "case"
    _cli_refused(["case", "vulkan_thesis", "--frames", "200", "--out", str(out), "--no-progress"], out, capsys,
                 "--frames: run ", "no repeat within the first 20 frames", "a schedule whose state repeats")
