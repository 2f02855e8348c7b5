"""XR stereo: exact weak/strong timelines, strong never slower, simulated mode, no drift."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mgpusim import InputError, simulate
from tests.schedule_helpers import assert_no_drift, experiment, gpu, presents, profile, rows, timed


def xr(prof=None, ms_ns: int = 1000, **kw):
    kw.setdefault("width", 2)
    kw.setdefault("height", 2)
    kw.setdefault("cbpp", 3)
    kw.setdefault("dbpp", 3)
    kw.setdefault("fif", 3)
    kw.setdefault("warmup", 1)
    return simulate(experiment(prof or profile(), "xr", [timed("view", ms_ns)], **kw))


def test_weak_scaling_exact_timeline():
    """Each 2x2 eye (24 B of colour + depth) renders in 1000 ns; GPU 0's transfer queue copies
    its own view (d2d, 24 ns) then GPU 1's (d2h 24 + h2d 24), the present queue presents (10)."""
    r = xr(frames=3, scaling="weak")
    assert rows(r, "render0.view") == [(0, 1000), (1058, 2058), (2116, 3116)]
    assert rows(r, "render1.view") == [(0, 1000), (1058, 2058), (2116, 3116)]
    assert rows(r, "view0.d2d", 0) == [(1000, 1024)]
    assert rows(r, "view1.d2h", 0) == [(1000, 1024)] and rows(r, "view1.h2d", 0) == [(1024, 1048)]
    assert rows(r, "present", 0) == [(1048, 1058)]
    assert presents(r) == [1058, 2116, 3174]
    assert list(r.frames.latency_ns) == [1058] * 3
    engines = {(d, e) for d, e in zip(r.trace.device, r.trace.engine)}
    assert ("gpu0", "transfer") in engines and ("gpu0", "graphics#1") in engines
    assert set(r.trace[r.trace.step == "handoff"].task) == {"release0", "release1", "acquire"}


def test_strong_scaling_hides_the_transfer():
    r = xr(frames=3, scaling="strong")
    assert rows(r, "render0.view") == [(0, 1000), (1000, 2000), (2000, 3000)]
    assert presents(r) == [1058, 2058, 3058]
    assert list(r.frames.latency_ns) == [1058] * 3


@settings(max_examples=25, deadline=None)
@given(render=st.integers(2000, 5000), side=st.integers(1, 6), views=st.sampled_from([2, 4]),
       handoff=st.sampled_from([0.0, 0.01]))
def test_strong_never_slower_and_same_latency_with_short_transfers(render, side, views, handoff):
    prof = profile([gpu(count=4)])
    kw = dict(ms_ns=render, width=2 * side, height=side, gpus=views, frames=16, warmup=4,
              handoff_us=handoff)
    weak, strong = xr(prof, scaling="weak", **kw), xr(prof, scaling="strong", **kw)
    assert strong.summary["frame_time_ms"] <= weak.summary["frame_time_ms"]
    # transfers (< 1000 ns per frame on any queue) are shorter than the render: latency equal
    assert strong.summary["latency_ms"] == pytest.approx(weak.summary["latency_ms"], abs=1e-12)


def test_four_gpus_half_an_eye_each():
    r = xr(profile([gpu(count=4)]), gpus=4, width=4, frames=2)
    assert r.config["view_pixels"] == (4, 4, 4, 4)
    assert set(r.trace[r.trace.step == "render"].device) == {"gpu0", "gpu1", "gpu2", "gpu3"}


def test_simulated_mode_runs_everything_on_gpu0():
    r = xr(gpus=1, views=4, mode="simulated", width=4, frames=2)
    assert set(r.trace.device) == {"gpu0"}
    assert rows(r, "render3.view", 0) == [(3000, 4000)]  # views in turn on one queue
    assert set(r.trace[r.trace.bytes > 0].step) == {"d2d"}


def test_bad_configurations_rejected():
    with pytest.raises(InputError, match="views"):
        xr(gpus=2, views=4)
    with pytest.raises(InputError, match="frames_in_flight"):
        xr(fif=4)


@pytest.mark.parametrize("scaling", ["weak", "strong"])
def test_20000_frames_no_drift(scaling):
    r = simulate(experiment(profile(gbps=7 / 3, local_gbps=5 / 3), "xr", [timed("view", 1234)],
                            width=37, height=11, cbpp=3, dbpp=3, fif=3, frames=20_000,
                            scaling=scaling, handoff_us=0.333), record_trace=False)
    assert assert_no_drift(r.frames.present_ns) == 1


def test_device_group_copy_of_colour_and_depth_at_4_bytes_each():
    """The sample's transfer: the other GPU's eye as colour + depth at 4 B per pixel each
    (scene color/depth_bytes_per_pixel = 4), device to device over a peer link (a device
    group): a 2x2 eye is 32 B. GPU 0's transfer queue copies its own view (d2d at 1 B/ns,
    1000-1032), then pulls GPU 1's over the 2 B/ns link (1032-1048): one copy, no host memory."""
    r = xr(profile(peer_gbps=2.0), frames=2, cbpp=4, dbpp=4, path="peer")
    assert rows(r, "view0.d2d", 0) == [(1000, 1032)] and rows(r, "view1.p2p", 0) == [(1032, 1048)]
    assert set(r.trace[r.trace.task == "view1.p2p"].device) == {"gpu0"}
    assert not r.trace.step.isin(["d2h", "h2d", "host_copy"]).any()
    assert presents(r)[0] == 1058 and r.config["bytes_per_frame"] == 64


def test_device_group_copy_without_a_peer_link():
    """path = 'group': GPU 0's transfer queue pulls GPU 1's 32 B view over PCIe at the slower
    of GPU 1's d2h (4 B/ns) and GPU 0's h2d (2 B/ns): 1032-1048, after its own view's d2d."""
    r = xr(profile([gpu(gbps=2.0), gpu(gbps=4.0)]), frames=2, cbpp=4, dbpp=4, path="group")
    assert rows(r, "view0.d2d", 0) == [(1000, 1032)] and rows(r, "view1.group", 0) == [(1032, 1048)]
    assert set(r.trace[r.trace.task == "view1.group"].device) == {"gpu0"}
    assert presents(r)[0] == 1058
