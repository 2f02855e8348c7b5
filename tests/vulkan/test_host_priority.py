"""MGPUSIM_HOST_PRIORITY=realtime: lavapipe's threads and the runner's run under SCHED_FIFO;
the main thread keeps its policy; the default leaves every thread as it was."""
from __future__ import annotations

import json
import os
import threading

import pytest

from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.real.host import priority as host_priority
from mgpusim.real.runner import executor
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.instance import Instance
from mgpusim.real.vulkan.machine import machine_record

pytestmark = pytest.mark.vulkan


def _policy(tid: int) -> int:
    return os.sched_getscheduler(tid)


def _fifo_allowed() -> bool:
    """Whether this system lets the process use SCHED_FIFO (a throwaway thread tries)."""
    result: list[bool] = []
    t = threading.Thread(target=lambda: result.append(host_priority.promote()))
    t.start()
    t.join()
    return result[0]


def test_a_bad_setting_is_one_clear_error(monkeypatch):
    monkeypatch.setenv(host_priority.ENV, "fast")
    with pytest.raises(InputError, match="MGPUSIM_HOST_PRIORITY must be 'realtime' or 'normal'"):
        host_priority.wanted()


def test_only_threads_started_after_the_snapshot_are_promoted(monkeypatch):
    monkeypatch.setenv(host_priority.ENV, "realtime")
    if not _fifo_allowed():
        pytest.skip("this system refuses SCHED_FIFO")
    stop = threading.Event()
    old = threading.Thread(target=stop.wait)
    old.start()
    before = host_priority.snapshot()
    new = threading.Thread(target=stop.wait)
    new.start()
    try:
        host_priority.promote_new(before)
        assert _policy(new.native_id) == os.SCHED_FIFO
        assert _policy(old.native_id) == os.SCHED_OTHER
        assert _policy(threading.get_native_id()) == os.SCHED_OTHER
    finally:
        stop.set()
        old.join()
        new.join()


@pytest.mark.parametrize("setting", ["realtime", "normal"])
def test_a_lavapipe_gpu_threads_follow_the_setting(monkeypatch, setting):
    if setting == "realtime" and not _fifo_allowed():
        pytest.skip("this system refuses SCHED_FIFO")
    monkeypatch.setenv(host_priority.ENV, setting)
    before = host_priority.thread_ids()
    inst = Instance(lp_num_threads=2)
    gpu = Gpu(inst, 0, "gpu0")
    try:
        started = host_priority.thread_ids() - before
        assert len(started) >= 3  # two rasterizers and the queue thread at least
        policies = [_policy(t) for t in started]
        background = {os.SCHED_BATCH, os.SCHED_IDLE}  # the driver's own choice for a few
        if setting == "realtime":
            assert policies.count(os.SCHED_FIFO) >= 3
            assert set(policies) <= {os.SCHED_FIFO} | background
        else:
            assert os.SCHED_FIFO not in policies
        assert _policy(threading.get_native_id()) == os.SCHED_OTHER
        assert machine_record([gpu])["host_thread_priority"].startswith(setting)
    finally:
        gpu.close()
        inst.close()


def test_the_runner_threads_run_under_the_policy(monkeypatch, tmp_path):
    """In a measured run every runner thread works under SCHED_FIFO, and the machine record
    says so."""
    if not _fifo_allowed():
        pytest.skip("this system refuses SCHED_FIFO")
    monkeypatch.setenv(host_priority.ENV, "realtime")
    policies: list[int] = []
    guard = executor.Executor._guard

    def recording(self, fn, *args):
        def body(*a):
            policies.append(os.sched_getscheduler(0))
            return fn(*a)
        return guard(self, body, *args)

    monkeypatch.setattr(executor.Executor, "_guard", recording)
    main(["run", "experiments/lavapipe/afr.toml", "--set", "schedule.frames=6", "--set", "schedule.warmup_frames=2",
          "--set", "scene.width=32", "--set", "scene.height=32",
          "--set", "scene.passes.0.iterations=10", "--lp-threads", "2",
          "--out", str(tmp_path / "run")])
    record = json.loads((tmp_path / "run" / "machine.json").read_text())
    assert record["host_thread_priority"] == "realtime (SCHED_FIFO 1)"
    assert policies and set(policies) == {os.SCHED_FIFO}
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
