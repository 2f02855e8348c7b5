"""Shared builders for small, hand-computable profiles and experiments."""
from __future__ import annotations

import copy
import os
from typing import Any

import pytest

from mgpusim.model.profile import parse_profile
from mgpusim.schedules.experiment import parse_experiment

# The suite runs one process per core (pytest-xdist): a command under test forks no workers of
# its own beside them (tests of the workers clear this themselves)
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("MGPUSIM_WORKERS", "1")


def gpu_dict(transfer: int = 1, h2d: float = 1.0, d2h: float = 1.0, latency: int = 0,
             costs: dict | None = None) -> dict[str, Any]:
    """A GPU whose costs are easy to compute by hand (bandwidths in bytes per ns)."""
    return {
        "name": "TestGPU", "memory_bytes": 8 << 30,
        "queues": {"graphics": 1, "compute": 1, "transfer": transfer},
        "link": {"pcie_gen": 3, "lanes": 16, "latency_ns": latency, "h2d_gbps": h2d, "d2h_gbps": d2h},
        "costs": costs or {
            "fragment_loop": {"ns_per_pixel": 0.0, "ns_per_pixel_iteration": 1.0},
            "mesh": {"ns_per_pixel": 0.0, "ns_per_triangle": 1.0},
            "composite_sort_first": {"ns_per_pixel": 1.0, "ns_per_input": 0.0},
            "composite_sort_last": {"ns_per_pixel": 1.0, "ns_per_input": 0.0},
            "present": {"fixed_ns": 10, "ns_per_pixel": 0.0},
        },
    }


def profile_dict(gpus: int = 2, mem_gbps: float = 1.0, threads: int = 1, thread_gbps: float = 1.0,
                 **gpu_kw: Any) -> dict[str, Any]:
    return {
        "name": "test",
        "host": {"memory_bandwidth_gbps": mem_gbps, "memcpy_threads": threads,
                 "memcpy_thread_gbps": thread_gbps, "cpu_cores": 4},
        "gpus": [dict(gpu_dict(**gpu_kw), count=gpus)],
    }


def experiment_dict(schedule: str = "sort_first", gpus: int = 2, frames: int = 10, width: int = 8,
                    height: int = 4, iterations: int = 10, **sched: Any) -> dict[str, Any]:
    kind = "fragment_loop" if schedule == "sort_first" else "mesh"
    work = {"iterations": iterations} if kind == "fragment_loop" else {"triangles": iterations}
    return {
        "name": "t", "profile": "unused",
        "scene": {"width": width, "height": height,
                  "passes": [{"name": "p", "kind": kind, **work}]},
        "schedule": {"name": schedule, "gpus": gpus, "frames": frames, "warmup_frames": 2, **sched},
    }


def make_experiment(profile: dict | None = None, **kw: Any):
    prof = parse_profile(copy.deepcopy(profile or profile_dict()), "test-profile")
    return parse_experiment(experiment_dict(**kw), "test-experiment", profile=prof)


@pytest.fixture
def small_experiment():
    return make_experiment
