"""The advice's options for frames with filters, a temporal filter or a mesh run for real.

What each checks against one GPU's picture of the same scene:
- five-step sort-first / sort-last with filter passes: a filter samples its tile's outputs of
  the passes before it (images of their own), so the tiled frame equals the one-GPU frame;
- a temporal filter (inputs = one more than the passes before it) outside AFR samples its own
  output of the previous frame on the same GPU: every schedule gives the picture of one-GPU AFR
  with that pass as its temporal pass, after as many frames;
- a mesh under sort-first (a depth target, colour-only contributions) and under pipelining
  (output_bytes of its colour: the copy moves colour only; of colour + depth: both).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from mgpusim.real.runner import run_experiment

from .test_schedule_pictures import H, W, afr_passes, experiment, pipeline_passes, run
from .trace_checks import assert_runs_the_simulators_tasks

pytestmark = pytest.mark.vulkan

COLOUR = W * H * 4


def taa_passes() -> list[dict[str, Any]]:
    """A fragment loop and a TAA filter of it and of its own previous frame (the H100 study's
    temporal AA frame); output_bytes for pipelining's copies."""
    return [{**p, "output_bytes": COLOUR} for p in afr_passes("taa")]


@pytest.fixture(scope="module")
def taa_reference() -> np.ndarray:
    return run("afr", 1, taa_passes(), temporal_pass="taa").image


@pytest.mark.parametrize("schedule, gpus, options", [
    ("sort_first", 4, {"balance": True}), ("sort_first", 2, {"host_copy": False, "buffers": 1}),
    ("sort_last", 2, {"host_copy": False}), ("sort_first", 1, {}),
    ("pipelining", 2, {"split_at": 1, "chunks": 3}),
    ("pipelining", 2, {"split_at": 2, "buffers": 1}),
])
def test_a_temporal_filter_samples_its_own_previous_frame_outside_afr(taa_reference, schedule, gpus,
                                                                       options):
    result = run(schedule, gpus, taa_passes(), **options)
    assert len(np.unique(taa_reference[..., 0])) > 10
    assert np.array_equal(result.image, taa_reference)


def test_the_history_is_really_sampled(taa_reference):
    """The equality above can fail: one frame fewer accumulates another picture."""
    assert not np.array_equal(run("sort_first", 2, taa_passes(), frames=4).image, taa_reference)


@pytest.fixture(scope="module")
def chain_reference() -> np.ndarray:
    return run("pipelining", 1, pipeline_passes()).image


@pytest.mark.parametrize("schedule, gpus, options", [
    ("sort_first", 4, {"balance": True}), ("sort_first", 3, {"tile_rows": [10, 0, 38]}),
    ("sort_last", 2, {"host_copy": False}), ("sort_first", 1, {}),
])
def test_five_step_filters_sample_their_tiles_inputs(chain_reference, schedule, gpus, options):
    """The pipelining chain's filters (inputs 1, 2, 3) on tiles, an empty tile among them."""
    result = run(schedule, gpus, pipeline_passes(), **options)
    assert len(np.unique(chain_reference[..., 0])) > 10
    assert np.array_equal(result.image, chain_reference)


def mesh_passes(output: int = COLOUR, filtered: bool = False) -> list[dict[str, Any]]:
    mesh = [{"name": "tori", "kind": "mesh", "triangles": 3000, "output_bytes": output}]
    blur = {"name": "blur", "kind": "filter", "iterations": 5, "inputs": 1}
    return mesh + ([blur] if filtered else [])


@pytest.fixture(scope="module")
def mesh_reference() -> dict[bool, np.ndarray]:
    """One GPU draws every triangle (and filters them)."""
    return {f: run("pipelining", 1, mesh_passes(filtered=f)).image for f in (False, True)}


@pytest.mark.parametrize("schedule, gpus, filtered, options", [
    ("sort_first", 2, False, {"balance": True}), ("sort_first", 3, False, {"host_copy": False}),
    ("sort_first", 2, True, {}), ("sort_last", 1, False, {}),
    ("pipelining", 2, False, {"split_at": 1, "chunks": 4}),
    ("pipelining", 2, True, {"split_at": 1, "chunks": 2, "host_copy": True}),
    ("pipelining", 2, False, {"split_at": 1, "output": W * H * 6}),
])
def test_a_mesh_runs_under_sort_first_and_pipelining(mesh_reference, schedule, gpus, filtered,
                                                     options):
    """Sort-first tiles of a mesh (a depth target per tile, colour crosses) equal the one-GPU
    frame up to the rounding of interpolated colours (a tile's viewport is shifted: lavapipe
    may round a channel of a rare pixel the other way); the pipelined mesh crosses as colour,
    or with its depth where output_bytes count it, and is exact."""
    options = dict(options)
    result = run(schedule, gpus, mesh_passes(options.pop("output", COLOUR), filtered), **options)
    ref = mesh_reference[filtered]
    assert len(np.unique(ref[..., 0])) > 10
    if schedule == "pipelining":
        assert np.array_equal(result.image, ref)
        return
    off = np.abs(result.image.astype(int) - ref).max(axis=2)
    assert off.max() <= 1 and np.count_nonzero(off) <= off.size // 200


@pytest.mark.parametrize("schedule, gpus, passes, options", [
    ("sort_first", 3, taa_passes(), {"balance": True}),
    ("sort_last", 2, pipeline_passes(), {"host_copy": False}),
    ("sort_first", 2, mesh_passes(), {}),
    ("pipelining", 2, taa_passes(), {"split_at": 1, "chunks": 3, "consumer_waits": "reads"}),
])
def test_the_runner_runs_the_simulators_tasks(schedule, gpus, passes, options):
    """Same (frame, device, engine, step, task) rows as the simulator: the fixes bound
    images to the program's tasks, they added none; every dependency was honoured."""
    exp = experiment(schedule, gpus, passes, frames=4, **options)
    assert_runs_the_simulators_tasks(exp, run_experiment(exp, prewarm_frames=0).trace)


def sphere_passes() -> list[dict[str, Any]]:
    """vmgpu's mesh as vmgpu draws it: the sphere, its back faces culled."""
    return [{"name": "sphere", "kind": "mesh", "triangles": 4000, "shape": "sphere", "cull": "back",
             "output_bytes": COLOUR}]


@pytest.mark.parametrize("schedule, gpus", [("sort_last", 2), ("sort_first", 3)])
def test_vmgpus_sphere_runs_split_as_on_one_gpu(schedule, gpus):
    """The runner draws the sphere (no longer refused as the model's only): split by sort-last
    index ranges or sort-first tiles, the frame is the one-GPU frame (tiles up to the rounding
    of interpolated colours), and not the torus's."""
    ref = run("sort_first", 1, sphere_passes()).image
    assert not np.array_equal(ref, run("sort_first", 1, mesh_passes()).image)
    off = np.abs(run(schedule, gpus, sphere_passes()).image.astype(int) - ref).max(axis=2)
    assert off.max() <= 1 and np.count_nonzero(off) <= off.size // 200
