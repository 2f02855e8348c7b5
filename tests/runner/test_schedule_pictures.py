"""AFR, frame pipelining, XR and particle offload run for real and draw the right thing.

Each multi-GPU run is compared with what one GPU computes: AFR frames and the pipelined frame
with the 1-GPU run of the same schedule, XR's eyes with a whole-eye render of the pass
library, the offloaded particles with the numpy reference of the update.
"""
from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from mgpusim.model.errors import ScheduleError
from mgpusim.model.profile import parse_profile
from mgpusim.real.passes.particle_update import initial_state, reference_update
from mgpusim.real.passes.standalone import FragmentLoop, Mesh
from mgpusim.real.runner import run_experiment
from mgpusim.real.vulkan.copies import download
from mgpusim.real.vulkan.machine import close_gpus, make_gpus
from mgpusim.schedules.experiment import parse_experiment

from .conftest import lavapipe_profile
from .trace_checks import assert_runs_the_simulators_tasks

pytestmark = pytest.mark.vulkan

W, H = 64, 48


def profile(**queues: int) -> dict[str, Any]:
    prof = lavapipe_profile(transfer=queues.pop("transfer", 0))
    gpu = prof["gpus"][0]
    gpu["queues"].update(queues)
    gpu["costs"].update({"filter": {"ns_per_pixel": 1.0, "ns_per_pixel_iteration": 1.0,
                                    "ns_per_pixel_input": 1.0},
                         "particle_update": {"ns_per_particle": 1.0},
                         "particle_render": {"ns_per_particle": 1.0, "ns_per_pixel": 0.0}})
    return prof


def experiment(schedule: str, gpus: int, passes: list[dict], frames: int = 5,
               prof: dict | None = None, **sched: Any):
    data = {"name": f"{schedule}-{gpus}", "profile": "unused",
            "scene": {"width": W, "height": H, "passes": passes},
            "schedule": {"name": schedule, "gpus": gpus, "frames": frames, "warmup_frames": 1,
                         **sched}}
    return parse_experiment(data, "test-experiment",
                            profile=parse_profile(copy.deepcopy(prof or profile()), "test-profile"))


def run(*args: Any, prewarm: int | None = 0, read=(), **kw: Any):
    return run_experiment(experiment(*args, **kw), prewarm_frames=prewarm, read=read)


# -- AFR ---------------------------------------------------------------------------------------
def afr_passes(temporal: str) -> list[dict]:
    """A base pass and a filter; as the temporal pass the filter also samples the history."""
    return [{"name": "base", "kind": "fragment_loop", "iterations": 40},
            {"name": "taa", "kind": "filter", "iterations": 10, "inputs": 2 if temporal else 1}]


@pytest.fixture(scope="module")
def afr_reference():
    return {t: run("afr", 1, afr_passes(t), temporal_pass=t) for t in ("", "taa")}


@pytest.mark.parametrize("gpus, temporal, options", [
    (2, "", {}), (3, "", {"host_copy": True}),
    (2, "taa", {}), (3, "taa", {"host_copy": True}), (2, "taa", {"frames_in_flight": 3}),
])
def test_afr_frames_equal_one_gpu_frames(afr_reference, gpus, temporal, options):
    """The last frame (rendered on a secondary for 5 frames on 2 or 3 GPUs and copied to GPU 0)
    equals the 1-GPU frame; with the temporal pass it accumulated every earlier frame through
    the history copies F0 -> F1 -> F2 ..."""
    ref = afr_reference[temporal].image
    result = run("afr", gpus, afr_passes(temporal), temporal_pass=temporal, **options)
    assert len(np.unique(ref[..., 0])) > 10
    assert np.array_equal(result.image, ref)


def test_afr_temporal_pass_reads_the_previous_frame(afr_reference):
    """The check can fail: the temporal picture depends on the history and on how many frames
    it went through (one frame fewer gives another picture)."""
    temporal = afr_reference["taa"].image
    assert not np.array_equal(temporal, afr_reference[""].image)
    assert not np.array_equal(run("afr", 2, afr_passes("taa"), frames=4,
                                  temporal_pass="taa").image, temporal)


# -- frame pipelining ------------------------------------------------------------------------------
def pipeline_passes(output: int = W * H * 4) -> list[dict]:
    """GPU 1's passes a, b; GPU 0's filters c, d sample them (the case study's chain)."""
    return [{"name": "a", "kind": "fragment_loop", "iterations": 30, "output_bytes": output},
            {"name": "b", "kind": "filter", "iterations": 5, "inputs": 1, "output_bytes": output},
            {"name": "c", "kind": "filter", "iterations": 5, "inputs": 2},
            {"name": "d", "kind": "filter", "iterations": 5, "inputs": 3}]


@pytest.fixture(scope="module")
def pipeline_reference():
    return run("pipelining", 1, pipeline_passes()).image


@pytest.mark.parametrize("options", [
    {}, {"host_copy": True}, {"chunks": 4}, {"chunks": 8, "host_copy": True},
    {"chunks": 2, "copy_queue": "graphics"}, {"buffers": 1, "frames_in_flight": 1},
    {"copy_granularity": "frame"}, {"copy_granularity": "frame", "chunks": 4, "host_copy": True},
])
def test_pipelined_frame_equals_one_gpu_frame(pipeline_reference, options):
    result = run("pipelining", 2, pipeline_passes(), split_at=2, **options)
    assert len(np.unique(pipeline_reference[..., 0])) > 10
    assert np.array_equal(result.image, pipeline_reference)


def test_pipelining_copy_queue_falls_back_and_says_so(pipeline_reference):
    """A profile with a copy engine puts the copies on the transfer queue; lavapipe has none,
    so the runner records them on graphics and lists the fallback."""
    result = run("pipelining", 2, pipeline_passes(), prof=profile(transfer=1), split_at=2, chunks=2)
    assert np.array_equal(result.image, pipeline_reference)
    fallbacks = result.summary["queue_fallbacks"]
    assert "out.a#0.d2h: gpu1.transfer -> gpu1.graphics" in fallbacks
    assert "out.b#1.h2d: gpu0.transfer -> gpu0.graphics" in fallbacks


def test_pipelining_chunks_that_do_not_divide_the_height(pipeline_reference):
    """48 rows in 5 chunks: 9, 9, 9, 9 and 12 rows, each copy carrying its rows' bytes (the
    model's bytes), and the frame still equals one GPU's."""
    result = run("pipelining", 2, pipeline_passes(), split_at=2, chunks=5)
    assert np.array_equal(result.image, pipeline_reference)
    d2h = result.trace[(result.trace["step"] == "d2h") & result.trace["task"].str.startswith("out.a#")]
    row_bytes = W * 4
    per_chunk = d2h.groupby("task")["bytes"].first().sort_index()
    assert per_chunk.tolist() == [9 * row_bytes] * 4 + [12 * row_bytes]


def test_pipelining_chunks_must_have_a_row_each():
    with pytest.raises(ScheduleError, match="schedule.chunks = 49 is more than the image's 48 rows"):
        run("pipelining", 2, pipeline_passes(), split_at=2, chunks=49)


def test_wrong_pipeline_input_would_be_caught(pipeline_reference):
    """The equality can fail: GPU 0's filters show what GPU 1 sent (another pass on GPU 1,
    another picture)."""
    other = pipeline_passes()
    other[0]["iterations"] = 5000  # uv grows by 4 %: another picture on GPU 1
    assert not np.array_equal(run("pipelining", 2, other, split_at=2).image, pipeline_reference)


# -- XR ------------------------------------------------------------------------------------------
XR_PASSES = {"mesh": [{"name": "tori", "kind": "mesh", "triangles": 3000}],
             "fragment_loop": [{"name": "loop", "kind": "fragment_loop", "iterations": 30}]}


@pytest.fixture(scope="module")
def eye_renders():
    """Each eye rendered whole by the pass library on one GPU."""
    (gpu,) = make_gpus(1)
    out = {}
    for kind in XR_PASSES:
        for eye in (0, 1):
            p = (Mesh(gpu, W, H, 3000, eye=eye) if kind == "mesh"
                 else FragmentLoop(gpu, W, H, 30, eye=eye))
            gpu.run("graphics", p.record)
            out[kind, eye] = download(gpu, p.target.color).reshape(H, W, 4)
            p.destroy()
    close_gpus([gpu])
    return out


@pytest.mark.parametrize("kind", list(XR_PASSES))
@pytest.mark.parametrize("gpus, options", [
    (2, {}), (2, {"scaling": "strong", "frames_in_flight": 3}), (4, {"host_copy": True}),
    (4, {"scaling": "strong", "buffers": 3, "frames_in_flight": 2}),
    (1, {"mode": "simulated", "views": 4}),
    (1, {"mode": "simulated", "views": 2, "scaling": "strong"}),
])
def test_xr_views_equal_whole_eye_renders(eye_renders, kind, gpus, options):
    """2 views (an eye per GPU) or 4 (half an eye each) assemble both eyes exactly."""
    left, right = eye_renders[kind, 0], eye_renders[kind, 1]
    assert not np.array_equal(left, right)  # a real stereo pair
    result = run("xr", gpus, XR_PASSES[kind], frames=4, **options)
    assert result.image.shape == (H, 2 * W, 4)
    assert np.array_equal(result.image[:, :W], left)
    assert np.array_equal(result.image[:, W:], right)


def test_xr_transfer_and_present_queues_are_recorded(eye_renders):
    """A profile with a copy engine and a second graphics queue: the views go on the transfer
    queue, acquire and present on graphics#1; lavapipe runs them on its one queue, and says so."""
    result = run("xr", 2, XR_PASSES["mesh"], prof=profile(transfer=1, graphics=2), frames=4)
    assert np.array_equal(result.image[:, W:], eye_renders["mesh", 1])
    fallbacks = result.summary["queue_fallbacks"]
    assert "present: gpu0.graphics#1 -> gpu0.graphics" in fallbacks
    assert "view1.h2d: gpu0.transfer -> gpu0.graphics" in fallbacks


def test_peer_copies_are_refused_with_one_message():
    prof = profile()
    prof["peer_links"] = [{"gpus": [0, 1], "bandwidth_gbps": 50.0, "latency_ns": 0}]
    with pytest.raises(ScheduleError, match="peer and device-group copies are not supported by the runner"):
        run("xr", 2, XR_PASSES["mesh"], prof=prof, frames=2)


# -- particles ------------------------------------------------------------------------------------
P, FRAMES = 256, 12
ENGINE = [{"name": "shadow", "kind": "fragment_loop", "iterations": 20},
          {"name": "geometry", "kind": "fragment_loop", "iterations": 20},
          {"name": "lighting", "kind": "filter", "iterations": 200, "inputs": 2}]


def reference_particles(skipped: list[int]) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """numpy: the state after every update that ran (a skipped update's time step goes to the
    next one), and the vertices each of them built."""
    state, step, vertices = initial_state(P), 1, {}
    for f in range(FRAMES):
        if f in skipped:
            step += 1
            continue
        state, _calc, vertices[f] = reference_update(state, step / 60)
        step = 1
    return state, vertices


@pytest.mark.parametrize("gpus, options", [
    (2, {"policy": "wait"}), (2, {"policy": "wait", "host_copy": False}),
    (1, {"policy": "wait", "particle_gpu": 0}),
    (2, {"policy": "new_wait"}), (2, {"policy": "new_wait", "update_queue": "graphics"}),
    (1, {"policy": "new_wait", "particle_gpu": 0}),
])
def test_particles_match_numpy(gpus, options):
    """After 12 frames the particle GPU's state is numpy's after the updates that ran; the
    vertex buffer on GPU 0 holds the last update's billboards. 'wait' skips nothing and every
    draw shows its own frame's update; 'new_wait' draws the newest update that ran in frames
    <= f (on lavapipe's one queue the upload is queued before the draw): the draw lags by the
    updates skipped since, never more."""
    pg = options.get("particle_gpu", 1)
    result = run("particles", gpus, ENGINE, frames=FRAMES, particles=P,
                 read=[f"gpu{pg}.particles.state", "gpu0.particles.vertices"], **options)
    skipped = result.summary.get("skipped_frames", {}).get("particle_update", [])
    state, vertices = reference_particles(skipped)
    got = result.readback[f"gpu{pg}.particles.state"][0].view(np.float32).reshape(P, 4, 4)
    np.testing.assert_allclose(got, state, atol=1e-5)
    last = max(vertices)
    shown = result.readback["gpu0.particles.vertices"][last % 2].view(np.float32).reshape(P, 12, 4)
    np.testing.assert_allclose(shown, vertices[last], atol=1e-5)
    if options["policy"] == "wait":
        assert skipped == [] and "read_frames" not in result.summary
        return
    if gpus == 2:  # on one GPU a light frame's update may be done before the next decides
        assert skipped, "the chain outlasts a frame here: some updates must be skipped"
    read = result.summary["read_frames"]["particle_render"]
    assert read == [max(g for g in vertices if g <= f) for f in range(FRAMES)]
    assert result.summary.get("skipped_tasks", {}).get("particle_update", 0) == len(skipped)
    rates = result.summary["task_rates_hz"]
    # the steady-state rate: on one GPU the leader decides once the present two frames back has
    # ended, and a light frame's update may be done by then in every steady frame
    assert rates["particle_update"] <= rates["frames"] * (1 + 1e-9)  # equal where every update ran
    if gpus == 2:
        assert rates["particle_update"] < rates["frames"]


def test_new_wait_keeps_updating_while_the_primary_stays_busy():
    """'new_wait' skips an update only while the previous one's work is still running: on a
    primary that is never idle the chain's end is seen at its fences, not when the reap thread
    (which reads timestamps in queue order, and on lavapipe waits for the queue to go idle)
    gets there. Before, every update after the first few was skipped (3 in 57 frames)."""
    busy = [{"name": "shadow", "kind": "fragment_loop", "iterations": 3000},
            {"name": "geometry", "kind": "fragment_loop", "iterations": 3000},
            {"name": "lighting", "kind": "filter", "iterations": 200, "inputs": 2}]
    frames = 40
    result = run("particles", 2, busy, frames=frames, particles=P, policy="new_wait")
    skipped = set(result.summary.get("skipped_frames", {}).get("particle_update", []))
    streak = longest = 0
    for f in range(frames):
        streak = streak + 1 if f in skipped else 0
        longest = max(longest, streak)
    assert longest <= 4, f"updates starved: skipped frames {sorted(skipped)}"
    assert frames - len(skipped) >= frames // 5


def test_one_gpu_new_wait_decides_once_its_inputs_have_ended():
    """On one GPU the update's inputs (the present two frames back) run on the device before
    it; ordered behind them there, the submit thread ran frames ahead, found the previous update
    still queued and skipped 57 of 60 updates (97-99 % in the H100 runs), where the model skips
    at most every other one. The chain's leader now waits for its inputs on the host."""
    busy = [{"name": "shadow", "kind": "fragment_loop", "iterations": 3000},
            {"name": "geometry", "kind": "fragment_loop", "iterations": 3000},
            {"name": "lighting", "kind": "filter", "iterations": 200, "inputs": 2}]
    frames = 40
    result = run("particles", 1, busy, frames=frames, particles=P, policy="new_wait", particle_gpu=0)
    skipped = result.summary.get("skipped_frames", {}).get("particle_update", [])
    assert frames - len(skipped) >= frames // 4, f"updates starved: skipped frames {skipped}"


# -- the trace is the schedule's ------------------------------------------------------------------
@pytest.mark.parametrize("schedule, gpus, passes, options", [
    ("afr", 3, afr_passes("taa"), {"temporal_pass": "taa", "host_copy": True}),
    ("pipelining", 2, pipeline_passes(), {"split_at": 2, "chunks": 2, "host_copy": True}),
    ("xr", 4, XR_PASSES["mesh"], {"scaling": "strong"}),
    # no compute queue in the profile: the update runs where lavapipe runs it, on graphics
    ("particles", 2, ENGINE, {"policy": "wait", "particles": P, "prof": profile(compute=0)}),
])
def test_measured_trace_has_the_simulators_rows_and_order(schedule, gpus, passes, options):
    """The runner executed the schedule's own FrameProgram: the same (frame, device, engine,
    step, task) rows as the simulator (from a profile with lavapipe's queues), and every
    dependency ended before its consumer began."""
    exp = experiment(schedule, gpus, passes, frames=4, **options)
    assert_runs_the_simulators_tasks(exp, run_experiment(exp, prewarm_frames=0).trace)


def test_pipelining_refuses_an_output_it_would_not_copy():
    """Everything on GPU 1: the last pass's output must cross to be presented; the model's
    output_bytes of 0 says it would not, and the runner says so instead of showing nothing."""
    with pytest.raises(ScheduleError, match="output of pass 'd', but its output_bytes is 0"):
        run("pipelining", 2, pipeline_passes(), split_at=4)
