"""CPU-emulated GPUs (lavapipe): simulated GPUs' passes share the host's cores."""
from __future__ import annotations

from mgpusim import simulate
from tests.conftest import make_experiment, profile_dict


def lavapipe_profile(cores: int, threads: int | None) -> dict:
    prof = profile_dict(gpus=2)
    prof["host"].update(cpu_cores=cores, gpus_share_cpu=True)
    if threads is not None:
        prof["gpus"][0]["cpu_threads"] = threads
    return prof


def renders(exp, names=("render0", "render1")) -> dict:
    t = simulate(exp).trace
    f0 = t[t.frame == 0].set_index("task")
    return {name: int(f0.loc[name, "end_ns"] - f0.loc[name, "start_ns"]) for name in names}


def test_concurrent_renders_share_the_cores():
    # 8x4 sort-first, 2 tiles of 16 px x 100 iterations = 1600 ns each on an idle machine.
    alone = renders(make_experiment(lavapipe_profile(2, None), gpus=1, iterations=100, width=8, height=2),
                    names=("render0",))
    assert alone == {"render0": 1600}
    both = renders(make_experiment(lavapipe_profile(2, None), gpus=2, iterations=100))
    assert both == {"render0": 3200, "render1": 3200}  # 2 GPUs x 2 threads on 2 cores: half speed


def test_enough_cores_means_no_slowdown():
    both = renders(make_experiment(lavapipe_profile(4, 2), gpus=2, iterations=100))
    assert both == {"render0": 1600, "render1": 1600}
    result = simulate(make_experiment(lavapipe_profile(4, 2), gpus=2, iterations=100))
    assert result.summary["effects"]["cpu_contention"] is True


def test_real_gpus_report_no_cpu_effect():
    assert "cpu_contention" not in simulate(make_experiment(gpus=2)).summary["effects"]
