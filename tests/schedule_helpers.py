"""Small, hand-computable profiles and experiments for the AFR, pipelining, XR, particle,
memory and balancing tests. Passes are `timed` (duration_ms, 1 ns per reference ns), links
move 1 byte per ns by default, and nothing has a fixed cost unless a test sets one."""
from __future__ import annotations

import copy
from typing import Any

from mgpusim.model.profile import parse_profile
from mgpusim.schedules.experiment import parse_experiment

COSTS = {
    "present": {"fixed_ns": 10, "ns_per_pixel": 0.0},
    "particle_update": {"ns_per_particle": 1.0},
    "particle_render": {"fixed_ns": 5, "ns_per_particle": 0.0, "ns_per_pixel": 0.0},
    "fragment_loop": {"ns_per_pixel": 0.0, "ns_per_pixel_iteration": 1.0},
    "composite_sort_first": {"ns_per_pixel": 0.0, "ns_per_input": 0.0},
    "mesh": {"ns_per_pixel": 0.0, "ns_per_triangle": 1.0},
    "composite_sort_last": {"ns_per_pixel": 0.0, "ns_per_input": 0.0},
}


def gpu(graphics: int = 2, compute: int = 1, transfer: int = 1, gbps: float = 1.0, local_gbps: float = 1.0,
        memory: int = 8 << 30, costs: dict | None = None, count: int = 1) -> dict[str, Any]:
    return {"name": "G", "count": count, "memory_bytes": memory, "local_copy_gbps": local_gbps,
            "queues": {"graphics": graphics, "compute": compute, "transfer": transfer},
            "link": {"pcie_gen": 3, "lanes": 16, "latency_ns": 0, "h2d_gbps": gbps, "d2h_gbps": gbps},
            "costs": copy.deepcopy(costs or COSTS)}


def profile(gpus: list[dict] | None = None, peer_gbps: float | None = None, **kw: Any):
    data = {"name": "test", "host": {"memory_bandwidth_gbps": 1.0, "memcpy_threads": 1,
                                     "memcpy_thread_gbps": 1.0, "cpu_cores": 4},
            "gpus": gpus or [gpu(count=2, **kw)]}
    if peer_gbps:
        data["peer_links"] = [{"gpus": [0, 1], "bandwidth_gbps": peer_gbps, "latency_ns": 0}]
    return parse_profile(data, "test-profile")


def timed(name: str, ns: int, **params: Any) -> dict[str, Any]:
    return {"name": name, "kind": "timed", "duration_ms": ns / 1e6, **params}


def experiment(prof, schedule: str, passes: list[dict], gpus: int = 2, frames: int = 10,
               width: int = 4, height: int = 2, fif: int = 2, warmup: int = 2, cbpp: int = 4,
               dbpp: int = 2, dataset: int = 0, **opts: Any):
    data = {"name": "t", "scene": {"width": width, "height": height, "passes": passes,
                                   "color_bytes_per_pixel": cbpp, "depth_bytes_per_pixel": dbpp,
                                   "dataset_bytes": dataset},
            "schedule": {"name": schedule, "gpus": gpus, "frames": frames, "warmup_frames": warmup,
                         "frames_in_flight": fif, **opts}}
    return parse_experiment(data, "test-experiment", profile=prof)


def rows(result, task: str, frame: int | None = None) -> list[tuple[int, int]]:
    """(start_ns, end_ns) of a task, by frame order."""
    t = result.trace
    t = t[t.task == task] if frame is None else t[(t.task == task) & (t.frame == frame)]
    t = t.sort_values("frame")
    return list(zip(t.start_ns.astype(int), t.end_ns.astype(int)))


def presents(result) -> list[int]:
    return [int(x) for x in result.frames.present_ns]


def assert_no_drift(present_ns, skip: int = 100, max_cycle: int = 6) -> int:
    """Presents repeat with a fixed cycle of k frames (k = 1 for most schedules; AFR and
    schedules that alternate settle into k > 1), and the last present lands exactly where
    integer arithmetic says. Returns k."""
    import numpy as np
    p = np.asarray(present_ns, dtype=np.int64)[skip:]
    for k in range(1, max_cycle + 1):
        d = p[k:] - p[:-k]
        if d.min() == d.max():
            n = (len(p) - 1) // k
            assert p[n * k] == p[0] + n * int(d[0])
            return k
    raise AssertionError(f"no constant cycle of <= {max_cycle} frames")
