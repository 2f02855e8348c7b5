"""Runner tests on lavapipe, with the Khronos validation layer on (as in tests/vulkan)."""
from __future__ import annotations

import copy
import os
from typing import Any

import pytest

os.environ["MGPUSIM_VK_VALIDATION"] = "1"

from mgpusim.model.errors import DependencyError  # noqa: E402
from mgpusim.model.profile import parse_profile  # noqa: E402
from mgpusim.real.vulkan import instance as vkinst  # noqa: E402
from mgpusim.schedules.experiment import parse_experiment  # noqa: E402


def lavapipe_profile(gpus: int = 4, transfer: int = 0, threads: int = 2) -> dict[str, Any]:
    """A profile shaped like lavapipe: one queue family (no copy engine) per GPU."""
    fl = {"ns_per_pixel": 0.0, "ns_per_pixel_iteration": 1.0}
    return {
        "name": "lavapipe-test",
        "host": {"memory_bandwidth_gbps": 10.0, "memcpy_threads": threads,
                 "memcpy_thread_gbps": 5.0, "cpu_cores": 2},
        "gpus": [{"name": "llvmpipe", "memory_bytes": 1 << 30, "count": gpus,
                  "queues": {"graphics": 1, "compute": 1, "transfer": transfer},
                  "link": {"pcie_gen": 3, "lanes": 16, "latency_ns": 0, "h2d_gbps": 5.0,
                           "d2h_gbps": 5.0},
                  "costs": {"fragment_loop": fl,
                            "mesh": {"ns_per_pixel": 0.0, "ns_per_triangle": 1.0},
                            "composite_sort_first": {"ns_per_pixel": 1.0, "ns_per_input": 0.0},
                            "composite_sort_last": {"ns_per_pixel": 1.0, "ns_per_input": 0.0},
                            "present": {"fixed_ns": 10, "ns_per_pixel": 0.0}}}],
    }


def experiment(schedule: str = "sort_first", gpus: int = 2, width: int = 64, height: int = 48,
               work: int = 40, frames: int = 5, profile: dict | None = None, **sched: Any):
    """A small experiment: fragment loop (sort-first) or a torus mesh (sort-last)."""
    pass_ = ({"name": "p", "kind": "fragment_loop", "iterations": work} if schedule == "sort_first"
             else {"name": "p", "kind": "mesh", "triangles": work})
    data = {"name": f"{schedule}-{gpus}", "profile": "unused",
            "scene": {"width": width, "height": height, "passes": [pass_]},
            "schedule": {"name": schedule, "gpus": gpus, "frames": frames, "warmup_frames": 1,
                         **sched}}
    prof = parse_profile(copy.deepcopy(profile or lavapipe_profile()), "test-profile")
    return parse_experiment(data, "test-experiment", profile=prof)


@pytest.fixture(scope="session", autouse=True)
def vulkan_available():
    try:
        vkinst.Instance().close()
    except DependencyError as exc:
        pytest.skip(f"no usable Vulkan: {exc}")
    yield
    errors = vkinst.validation_errors()
    assert not errors, f"{len(errors)} validation error(s), first: {errors[0]}"


def pytest_collection_modifyitems(items):
    for item in items:
        if "tests/runner" in str(item.fspath).replace(os.sep, "/"):
            assert item.get_closest_marker("vulkan"), f"{item.nodeid} lacks @pytest.mark.vulkan"
