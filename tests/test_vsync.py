"""Vsync (`schedule.refresh_hz`): the present waits for the display's next refresh, for any
schedule; exact timelines on a hand-computable frame."""
from __future__ import annotations

import pytest

from mgpusim import InputError, simulate
from mgpusim.schedules.program import build_program
from tests.schedule_helpers import experiment, presents, profile, rows, timed


def one_gpu(ns: int, **kw):
    kw.setdefault("frames", 6)
    return experiment(profile(), "pipelining", [timed("a", ns)], gpus=1, warmup=1, **kw)


def test_present_waits_for_the_next_refresh():
    """10 kHz: a refresh every 100,000 ns. A frame is 150,000 ns of work + a 10 ns present, two
    frames in flight. Frame 0: a 0-150,000, present work -150,010, shown at 200,000. Frame 1:
    a 150,010-300,010, present -300,020, shown 400,000. Frame 2 waits for frame 0's flip (done)
    and the queue: a 300,020-450,020, shown 500,000; frame 3 shown 700,000, ... : 1.5 refreshes
    a frame judder into periods of 200,000 and 100,000 ns. Without vsync: one per 150,010."""
    r = simulate(one_gpu(150_000, refresh_hz=10_000.0))
    assert presents(r) == [200_000, 400_000, 500_000, 700_000, 800_000, 1_000_000]
    assert rows(r, "present")[:2] == [(150_000, 150_010), (300_010, 300_020)]
    assert r.summary["fast_forward"]["used"] is False and "vsync" in r.summary["fast_forward"]["why"]
    free = simulate(one_gpu(150_000))
    assert presents(free)[:2] == [150_010, 300_020]


def test_refresh_grid_is_exact_for_any_rate():
    """90 Hz: refresh k at k x 10^9 / 90 ns rounded half up (11,111,111, 22,222,222, ...,
    88,888,889, 100,000,000). One frame in flight and 5 ms of work: every frame shows at the
    next refresh, one per refresh."""
    r = simulate(one_gpu(5_000_000, fif=1, frames=10, refresh_hz=90.0))
    assert presents(r) == [(2 * k * 10**9 + 90) // 180 for k in range(1, 11)]
    assert presents(r)[7:9] == [88_888_889, 100_000_000]


def test_vsync_is_simulated_only():
    with pytest.raises(InputError, match="schedule.refresh_hz"):
        simulate(one_gpu(1000, refresh_hz=60.0), fidelity="analytic")
    assert simulate(one_gpu(1000, refresh_hz=60.0), fidelity="queues").frames.present_ns.iloc[0] == 16_666_667
    present = next(t for t in build_program(one_gpu(1000, refresh_hz=60.0)).templates[0]
                   if t.name == "present")
    assert "vsync" in present.params["unsupported"]  # the Vulkan runner refuses it
    with pytest.raises(InputError, match="schedule.refresh_hz"):
        one_gpu(1000, refresh_hz=-60.0)
    with pytest.raises(InputError, match="schedule.refresh_hz"):
        one_gpu(1000, refresh_hz=1e9)
