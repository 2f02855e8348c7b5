"""The fast-forward on AFR with many GPUs: 8 GPUs with 8 frames in flight drift for about 1,340
frames before their state repeats (each GPU's phase settles against the others'); the
fast-forwarded run equals the event-by-event one, trace, frames, links and summary, and the
repeat is found within one period of the frame from which the event-by-event run repeats."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mgpusim import load_experiment, simulate

ROOT = Path(__file__).resolve().parents[1]


def _afr(gpus: int, frames: int):
    return load_experiment(ROOT / "experiments" / "afr_tc1.toml", {
        "schedule.gpus": gpus, "profile.gpu_count": gpus, "schedule.frames_in_flight": gpus,
        "schedule.frames": frames})


def test_afr_on_8_gpus_fast_forwarded_equals_the_event_by_event_run():
    exp = _afr(8, 2000)
    off, on = simulate(exp, fast_forward=False), simulate(exp)
    ff = on.summary["fast_forward"]
    assert ff["used"] and ff["period_frames"] == 8 and ff["frames_skipped"] > 0
    assert {k: v for k, v in on.summary.items() if k != "fast_forward"} == \
        {k: v for k, v in off.summary.items() if k != "fast_forward"}
    pd.testing.assert_frame_equal(on.frames, off.frames)
    pd.testing.assert_frame_equal(on.trace, off.trace)
    pd.testing.assert_frame_equal(on.links.reset_index(drop=True), off.links.reset_index(drop=True))
    # found as soon as the run repeats: within one period of the first frame from which every
    # frame's start and present repeat (the run's last frames left out: its end does not)
    start = off.frames["start_ns"].to_numpy(np.int64)
    present = off.frames["present_ns"].to_numpy(np.int64)
    p, shift = ff["period_frames"], ff["period_ns"]
    same = (start[p:] - start[:-p] == shift) & (present[p:] - present[:-p] == shift)
    onset = int(np.flatnonzero(~same[:len(same) - 60])[-1]) + 1
    assert onset <= ff["from_frame"] <= onset + p
