"""Vulkan backend tests on lavapipe, with the Khronos validation layer on for the whole run.

MGPUSIM_VK_VALIDATION=1 is set before any instance exists, so every Instance (also those the
CLI creates) enables the layer and its debug-utils messenger; the session fixture fails the run
at teardown if the layer reported any error.
"""
from __future__ import annotations

import os

import pytest

os.environ["MGPUSIM_VK_VALIDATION"] = "1"

from mgpusim.model.errors import DependencyError  # noqa: E402
from mgpusim.real.vulkan import instance as vkinst  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def validation_clean():
    """Fail the session if the validation layer reported an error anywhere in the run."""
    yield
    errors = vkinst.validation_errors()
    assert not errors, f"{len(errors)} validation error(s), first: {errors[0]}"


@pytest.fixture(scope="session")
def instance():
    try:
        inst = vkinst.Instance()
    except DependencyError as exc:
        pytest.skip(f"no usable Vulkan: {exc}")
    yield inst
    inst.close()


@pytest.fixture(scope="session")
def gpu(instance):
    from mgpusim.real.vulkan.device import Gpu

    g = Gpu(instance, 0, "gpu0")
    yield g
    g.close()


def pytest_collection_modifyitems(items):
    for item in items:
        if "tests/vulkan" in str(item.fspath).replace(os.sep, "/"):
            assert item.get_closest_marker("vulkan"), f"{item.nodeid} lacks @pytest.mark.vulkan"
