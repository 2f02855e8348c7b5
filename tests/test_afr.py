"""AFR: exact timelines, N x speed-up with free copies, temporal copies, no drift."""
from __future__ import annotations

import pytest

from mgpusim import simulate
from tests.schedule_helpers import experiment, gpu, presents, profile, rows, timed


def test_ideal_two_gpus_exact_timeline():
    """1000 ns frames; GPU 1's 32-byte image crosses at 1 B/ns (d2h 32 + h2d 32) before GPU 0
    presents it (10 ns) on its second graphics queue; each GPU waits for present f-2."""
    r = simulate(experiment(profile(), "afr", [timed("a", 1000)], frames=6))
    assert presents(r) == [1010, 1074, 2020, 2148, 3030, 3222]
    assert rows(r, "render.a") == [(0, 1000), (0, 1000), (1010, 2010), (1074, 2074), (2020, 3020), (2148, 3148)]
    assert rows(r, "out.d2h") == [(1000, 1032), (2074, 2106), (3148, 3180)]
    assert rows(r, "out.h2d") == [(1032, 1064), (2106, 2138), (3180, 3212)]
    assert set(r.trace[r.trace.task == "present"].engine) == {"graphics#1"}
    # pacing is reported, not averaged away: periods alternate, so jitter > 0
    assert r.summary["frame_time_jitter_ms"] > 0


def test_temporal_dependency_copies_history_and_leaves_gaps():
    """The 'taa' pass of frame f waits for frame f-1's 100-byte history (d2h + h2d = 200 ns)."""
    r = simulate(experiment(profile(), "afr", [timed("a", 1000), timed("taa", 500)], frames=4,
                            temporal_pass="taa", history_bytes=100))
    assert rows(r, "render.taa") == [(1000, 1500), (1700, 2200), (2510, 3010), (3442, 3942)]
    assert rows(r, "hist.d2h") == [(1500, 1600), (2200, 2300), (3010, 3110), (3942, 4042)]
    assert rows(r, "hist.h2d") == [(1600, 1700), (2300, 2400), (3110, 3210), (4042, 4142)]
    assert presents(r) == [1510, 2442, 3020, 4184]
    gpu1 = r.trace[(r.trace.device == "gpu1") & (r.trace.engine == "graphics")].sort_values("start_ns")
    assert int(gpu1.start_ns.iloc[1]) - int(gpu1.end_ns.iloc[0]) == 700  # idle gap 1000..1700


@pytest.mark.parametrize("n", [2, 3, 4])
def test_n_gpus_reach_n_times_the_frame_rate_with_free_copies(n):
    prof = profile([gpu(count=4, gbps=1e9, local_gbps=1e9)])
    one = simulate(experiment(prof, "afr", [timed("a", 1000)], gpus=1, fif=1, frames=60, warmup=12))
    many = simulate(experiment(prof, "afr", [timed("a", 1000)], gpus=n, fif=n, frames=60 * n, warmup=12))
    assert many.summary["fps"] >= n * one.summary["fps"] * (1 - 1e-9)
    assert many.summary["latency_ms"] >= one.summary["latency_ms"]


def test_copies_on_graphics_queue_when_asked_or_without_copy_engine():
    on_gfx = simulate(experiment(profile(), "afr", [timed("a", 1000)], frames=4, copy_queue="graphics"))
    no_ce = simulate(experiment(profile(transfer=0), "afr", [timed("a", 1000)], frames=4))
    for r in (on_gfx, no_ce):
        copies = r.trace[r.trace.step.isin(["d2h", "h2d"])]
        assert set(copies.engine) == {"graphics"}


def test_peer_link_makes_one_copy():
    r = simulate(experiment(profile(peer_gbps=4.0), "afr", [timed("a", 1000)], frames=4))
    assert set(r.trace[r.trace.bytes > 0].step) == {"p2p"}
    assert rows(r, "out.p2p", 1) == [(1000, 1008)]


def test_unknown_temporal_pass_is_an_input_error():
    from mgpusim import InputError
    with pytest.raises(InputError, match="temporal_pass"):
        simulate(experiment(profile(), "afr", [timed("a", 1000)], temporal_pass="nope"))


def test_20000_frames_no_drift():
    prof = profile(gbps=7 / 3)
    r = simulate(experiment(prof, "afr", [timed("a", 1000), timed("taa", 333)], frames=20_000,
                            width=37, height=11, temporal_pass="taa", history_bytes=1001),
                 record_trace=False)
    p = r.frames.present_ns.to_numpy()
    cycles = p[102::2] - p[100:-2:2]  # one period per GPU cycle (2 frames)
    assert cycles.min() == cycles.max()
    assert p[-2] == p[100] + (len(p) - 102) // 2 * int(cycles[0])
