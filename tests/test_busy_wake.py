"""busy_wake: a copy's thread woken just as another GPU's pass fills the host's cores."""
from __future__ import annotations

import copy
from fractions import Fraction

import pytest

from mgpusim import simulate
from mgpusim.calibration.busy_wake_fit import fit_busy_wake
from mgpusim.model.errors import InputError
from mgpusim.model.profile import parse_profile
from mgpusim.schedules.experiment import parse_experiment
from mgpusim.sim.busy_wake import BusyWake
from tests.conftest import profile_dict

TWO = Fraction(2)


def test_a_young_pass_of_another_gpu_makes_a_share_of_its_pairs_wait():
    """A pass of 2 cores x 5000 ns: a copy left behind 50 ns after its start waits `ns`, or the
    9900 core-ns of work the pass has left if less."""
    bw = BusyWake(share=0.5, ns=4000, window_ns=100, host_cores=2)
    bw.pass_started("gpu1", 1000, TWO, 5000)
    assert bw.copy_wait("gpu1", 1010) == 0  # its own GPU's pass: not this effect
    assert bw.copy_wait("gpu0", 1050) == 0  # credit 1/2
    assert bw.copy_wait("gpu0", 1060) == 0  # the pair (gpu1's pass, gpu0) counted already
    assert bw.copy_wait("gpu2", 1050) == 4000  # credit 1: waits
    bw.pass_ended("gpu1")
    long_wait = BusyWake(share=1.0, ns=50_000, window_ns=100, host_cores=2)
    long_wait.pass_started("gpu1", 2000, TWO, 5000)
    assert long_wait.copy_wait("gpu0", 2050) == 9900  # let go when the pass is done


def test_a_pass_older_than_the_window_or_ended_delays_nothing():
    bw = BusyWake(share=1.0, ns=4000, window_ns=100, host_cores=2)
    bw.pass_started("gpu1", 1000, TWO, 5000)
    assert bw.copy_wait("gpu0", 1101) == 0
    bw.pass_ended("gpu1")
    bw.pass_started("gpu2", 2000, TWO, 5000)
    bw.pass_ended("gpu2")
    assert bw.copy_wait("gpu0", 2001) == 0
    bw.pass_started("gpu2", 3000, TWO, 5000)  # a new pass: new pairs
    assert bw.copy_wait("gpu0", 3000) == 4000


def test_only_long_passes_that_fill_the_cores_count():
    bw = BusyWake(share=1.0, ns=4000, window_ns=100, host_cores=2)
    assert bw.fills(Fraction(199, 100), 5000)
    assert not bw.fills(Fraction(147, 100), 5000)  # a mesh pass leaves a core free
    assert not bw.fills(TWO, 99)  # over before the window is


def test_the_state_is_relative_to_now_and_forgets_old_pairs():
    a, b = BusyWake(0.5, 4000, 100, 2), BusyWake(0.5, 4000, 100, 2)
    a.pass_started("gpu1", 1000, TWO, 5000)
    b.pass_started("gpu1", 5000, TWO, 5000)
    assert a.state(1040) == b.state(5040)
    a.copy_wait("gpu0", 1050)
    assert a.state(1060) != b.state(5060)  # a counted a pair and holds half a credit
    a.pass_ended("gpu1"), b.pass_ended("gpu1")
    assert a.state(1200)[1:] == b.state(5200)[1:] == ((), ())


def afr_on_shared_cores(share: float, ns: int = 3_000_000, gpus: int = 3, frames: int = 40,
                        iterations: int = 40_000, window_ns: int = 1_000_000):
    """Alternate-frame rendering of 3 GPUs on 2 shared cores at lavapipe's scale (passes of
    5 ms, a 1 ms window): the primary's upload of a secondary's frame comes just after the next
    frame's render (on another GPU) starts."""
    # no transfer queue: the copies run on the graphics queue, after the render, as on lavapipe
    prof = profile_dict(gpus=gpus, mem_gbps=10.0, thread_gbps=10.0, transfer=0)
    prof["host"].update(cpu_cores=2, gpus_share_cpu=True, dispatch_ns=200, busy_wake_share=share,
                        busy_wake_ns=ns, busy_wake_window_ns=window_ns)
    prof["gpus"][0]["cpu_threads"] = 2
    exp = {"name": "t", "profile": "unused",
           "scene": {"width": 16, "height": 8,
                     "passes": [{"name": "p", "kind": "fragment_loop", "iterations": iterations}]},
           "schedule": {"name": "afr", "gpus": gpus, "frames": frames, "warmup_frames": 4}}
    return parse_experiment(exp, "t", profile=parse_profile(copy.deepcopy(prof), "t")), prof


@pytest.mark.parametrize("share,ns", [(0.0, 3_000_000), (0.5, 3_000_000), (1.0, 3_000_000),
                                      (1.0, 50_000_000)])
def test_the_calibration_measures_what_the_model_puts_in(share, ns):
    """Traces simulated with the effect give back its share and wait (a wait longer than the
    pass is cut at its end: then all the fit can say is how long the pass had left)."""
    exp, prof = afr_on_shared_cores(share, ns)
    found = fit_busy_wake([(exp, simulate(exp).trace)], prof, 1_000_000)
    assert found is not None and found.pairs >= 10
    assert found.share == pytest.approx(share, abs=0.05)
    if share and ns < 5_000_000:
        assert found.ns == pytest.approx(ns, rel=0.1) and found.full_waits >= 5
    if ns > 5_000_000:
        assert found.full_waits == 0 and 5_000_000 < found.ns < 11_000_000


def test_one_gpu_has_nothing_to_measure():
    one, prof = afr_on_shared_cores(1.0, gpus=1)
    assert fit_busy_wake([(one, simulate(one).trace)], prof, 1_000_000) is None


def test_the_waits_slow_the_frames_and_are_exact_under_fast_forward():
    times = {}
    for share in (0.0, 0.5, 1.0):
        exp, _ = afr_on_shared_cores(share, frames=400, iterations=20, ns=30_000, window_ns=1000)
        fast = simulate(exp)
        slow = simulate(exp, fast_forward=False)
        assert fast.summary["frame_time_ms"] == slow.summary["frame_time_ms"]
        assert ("busy_wake" in fast.summary["modelled_effects"]) == (share > 0)
        times[share] = fast.summary["frame_time_ms"]
    assert times[0.0] < times[0.5] < times[1.0]
    exp, _ = afr_on_shared_cores(1.0)
    assert simulate(exp, effects={"busy_wake": False}).summary["frame_time_ms"] == pytest.approx(
        simulate(afr_on_shared_cores(0.0)[0]).summary["frame_time_ms"])
    assert simulate(exp).summary["frame_time_ms"] > simulate(afr_on_shared_cores(0.0)[0]).summary[
        "frame_time_ms"]


@pytest.mark.parametrize("key,value", [("busy_wake_share", 1.5), ("busy_wake_ns", -1),
                                       ("busy_wake_window_ns", 0.5)])
def test_a_bad_share_or_time_is_refused(key, value):
    prof = profile_dict(gpus=2)
    prof["host"][key] = value
    with pytest.raises(InputError, match=key):
        parse_profile(prof, "t")


def test_the_recipe_writes_the_measured_effect_into_the_profile():
    """The calibration step sets the host's three keys and says what it measured; on 1-GPU runs
    it leaves the effect off."""
    from mgpusim.calibration.recipe import _busy_wake
    exp, prof = afr_on_shared_cores(0.5)
    data = copy.deepcopy(prof)
    for key in ("busy_wake_share", "busy_wake_ns", "busy_wake_window_ns"):
        del data["host"][key]
    line = _busy_wake(data, [(exp, simulate(exp).trace)])
    assert data["host"]["busy_wake_share"] == pytest.approx(0.5, abs=0.05)
    assert data["host"]["busy_wake_ns"] == pytest.approx(3_000_000, rel=0.1)
    assert data["host"]["busy_wake_window_ns"] == 1_000_000
    assert "busy_wake_share = 0.5" in line
    one, _ = afr_on_shared_cores(0.5, gpus=1)
    untouched = copy.deepcopy(data["host"])
    assert "off" in _busy_wake(data, [(one, simulate(one).trace)])
    assert data["host"] == untouched
