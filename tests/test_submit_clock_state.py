"""The fast-forward and a queue's submit thread that runs ahead of its queue: on one GPU with a
submit cost (lavapipe's `submit_ns`) the thread's clock falls further behind every frame; once
every task left in the run could not bring it back up to now it is the same state whatever its
value, and the run repeats (it never did before)."""
from __future__ import annotations

from mgpusim import simulate
from tests.conftest import make_experiment, profile_dict


def _one_gpu(submit_ns: int, frames: int):
    prof = profile_dict(gpus=1)
    prof["host"].update(submit_ns=submit_ns, cpu_cores=2, gpus_share_cpu=True)
    return make_experiment(prof, gpus=1, frames=frames, iterations=200)


def test_a_lagging_submit_clock_repeats_and_changes_nothing():
    exp = _one_gpu(submit_ns=7, frames=3000)
    fast = simulate(exp, record_trace=False)
    slow = simulate(exp, record_trace=False, fast_forward=False)
    assert fast.summary["fast_forward"]["used"] is True
    assert fast.frames.present_ns.tolist() == slow.frames.present_ns.tolist()


def test_a_submit_clock_that_binds_stays_in_the_state():
    """A submit cost larger than a frame's work: the thread is behind the queue, its clock is
    ahead of now at every present, and the run is submit-bound (each frame the submit time)."""
    exp = _one_gpu(submit_ns=10_000, frames=200)
    r = simulate(exp)
    gaps = r.frames.present_ns.diff().dropna()
    assert (gaps >= 10_000).all()
    slow = simulate(exp, fast_forward=False)
    assert r.frames.present_ns.tolist() == slow.frames.present_ns.tolist()
