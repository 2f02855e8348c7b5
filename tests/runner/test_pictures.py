"""The composited picture of a multi-GPU run equals the single-GPU picture."""
from __future__ import annotations

import numpy as np
import pytest

from mgpusim.real.runner import run_experiment

from .conftest import experiment

pytestmark = pytest.mark.vulkan


@pytest.fixture(scope="module")
def sort_first_reference():
    return run_experiment(experiment("sort_first", 1, frames=3))


@pytest.fixture(scope="module")
def sort_last_reference():
    return run_experiment(experiment("sort_last", 1, work=3000, frames=3))


@pytest.mark.parametrize("gpus, options", [
    (2, {}), (3, {"host_copy": False}), (4, {}), (3, {"tile_rows": [5, 30, 13]}),
])
def test_sort_first_equals_single_gpu_exactly(sort_first_reference, gpus, options):
    ref = sort_first_reference.image
    assert ref.shape == (48, 64, 4) and len(np.unique(ref[..., 0])) > 10  # a real gradient
    result = run_experiment(experiment("sort_first", gpus, frames=4, **options))
    assert np.array_equal(result.image, ref)


@pytest.mark.parametrize("gpus, host_copy", [(2, False), (4, True)])
def test_sort_last_equals_single_gpu_up_to_depth_ties(sort_last_reference, gpus, host_copy):
    ref = sort_last_reference
    covered = ref.image[..., 3] == 255
    assert 0.05 < covered.mean() < 0.95  # the torus is on screen, not everywhere
    result = run_experiment(experiment("sort_last", gpus, work=3000, frames=4, host_copy=host_copy))
    assert result.depth is not None and ref.depth is not None
    assert np.array_equal(result.depth, ref.depth)  # nearest fragment everywhere
    differs = np.any(result.image != ref.image, axis=-1)
    # a colour may differ only where two fragments tie in depth; none should with this mesh
    assert differs.mean() <= 0.001


def test_wrong_composite_would_be_caught(sort_first_reference):
    """The equality test can fail: a run with a different load renders a different picture."""
    other = run_experiment(experiment("sort_first", 2, work=400, frames=2))
    assert not np.array_equal(other.image, sort_first_reference.image)
