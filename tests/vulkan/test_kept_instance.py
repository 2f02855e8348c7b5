"""Real GPUs share one VkInstance per process; lavapipe GPUs keep one each.

Why: the NVIDIA driver refused a new instance after about 30 had been made and destroyed in one
process (a study's 31st run failed with VkErrorIncompatibleDriver); with the instance kept, 45
runs in one process ran on two H100s. Lavapipe sizes each instance's rasterizer pool when it is
made, so its instances are not shared."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from mgpusim.real.vulkan import machine as host_machine

pytestmark = pytest.mark.vulkan


class _FakeInstance:
    made = 0

    def __init__(self, *, validation=None, lp_num_threads=None, lavapipe=False):
        type(self).made += 1
        self.validation = bool(validation)
        self.devices = [SimpleNamespace(is_lavapipe=lavapipe)]
        self.closed = False

    def close(self):
        self.closed = True


def test_real_gpus_reuse_one_instance_and_lavapipe_does_not(monkeypatch):
    monkeypatch.setattr(host_machine, "_REAL_INSTANCES", {})
    monkeypatch.setattr(host_machine.atexit, "register", lambda fn: fn)
    monkeypatch.setattr(host_machine, "Instance", _FakeInstance)
    _FakeInstance.made = 0
    first = host_machine.instance_for(False, None)
    assert host_machine.instance_for(False, None) is first and _FakeInstance.made == 1
    assert host_machine.is_kept(first)
    host_machine.close_gpus([SimpleNamespace(instance=first, owns_instance=False, close=lambda: None)])
    assert not first.closed  # kept for the process
    validated = host_machine.instance_for(True, None)
    assert validated is not first and _FakeInstance.made == 2

    monkeypatch.setattr(host_machine, "_REAL_INSTANCES", {})
    monkeypatch.setattr(host_machine, "Instance",
                        lambda **kw: _FakeInstance(lavapipe=True, **kw))
    a, b = host_machine.instance_for(False, 4), host_machine.instance_for(False, 4)
    assert a is not b and not host_machine.is_kept(a)


def test_lavapipe_gpus_keep_no_instance(instance):
    """On lavapipe (this machine's device) each simulated GPU owns its instance, and closing
    the GPUs leaves nothing kept."""
    gpus = host_machine.make_gpus(2)
    try:
        assert all(g.owns_instance for g in gpus) and gpus[0].instance is not gpus[1].instance
        assert not host_machine._REAL_INSTANCES
    finally:
        host_machine.close_gpus(gpus)
