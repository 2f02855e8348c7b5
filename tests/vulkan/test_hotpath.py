"""The runner's per-task Vulkan calls made straight on the C library (`vulkan/hotpath.py`).

On real lavapipe with the validation layer on: a submission that waits for two semaphores another
signalled runs after it, and both finish (a semaphore array passed wrong, so that a wait has no
signal pending, fails the session's validation check). With a fake library: the
result codes a caller tells apart (a fence not signalled yet, a timeout) and a failing call
read as the binding's calls do, a VulkanError naming the call.
"""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import pytest

from mgpusim.real.vulkan import hotpath
from mgpusim.real.vulkan.vk_errors import VulkanError, vk

pytestmark = pytest.mark.vulkan


def _empty(cmd) -> None:
    """Nothing between the submission's two timestamps."""


def test_a_submission_waits_for_the_semaphore_another_signalled(gpu):
    first_sem = gpu.semaphore()
    gate = gpu.semaphore()
    for _ in range(20):  # recorded command buffers reused, arrays made once per slot
        first = gpu.submit("graphics", _empty, signal=[first_sem, gate], label="first", key="a")
        second = gpu.submit("graphics", _empty, wait=[first_sem, gate], label="second", key="b")
        (_s1, e1), (s2, _e2) = first.wait().raw_ticks(), second.wait().raw_ticks()
        assert s2 >= e1
    assert gpu.queue("graphics").recorded["a"], "the slot went back to its key"


def test_stamps_in_memory_are_the_query_pools(gpu):
    """On lavapipe a slot's command buffer copies its stamps to mapped memory; read from there
    they equal the query pool's own results (the read a real GPU's slot makes)."""
    sub = gpu.submit("graphics", _empty, label="stamped", key="stamped")
    from_memory = sub.wait().raw_ticks()
    slot = gpu.queue("graphics").recorded["stamped"][0]
    assert slot.stamps is not None and from_memory[0] <= from_memory[1]
    assert hotpath.read_ticks(gpu.device, replace(slot, stamps=None)) == from_memory


def _fake(result: int) -> SimpleNamespace:
    real = vk()
    lib = SimpleNamespace(vkWaitForFences=lambda *a: result, vkGetFenceStatus=lambda *a: result,
                          vkResetFences=lambda *a: result, vkQueueSubmit=lambda *a: result)
    return SimpleNamespace(lib=lib, ffi=real.ffi, exception_codes=real.exception_codes,
                           VK_STRUCTURE_TYPE_SUBMIT_INFO=real.VK_STRUCTURE_TYPE_SUBMIT_INFO,
                           VK_PIPELINE_STAGE_ALL_COMMANDS_BIT=real.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT)


@pytest.mark.parametrize("result, waited, looked", [(0, True, True), (2, False, None),
                                                    (1, None, False)])
def test_statuses_the_callers_tell_apart(monkeypatch, result, waited, looked):
    monkeypatch.setattr(hotpath, "vk", lambda: _fake(result))
    slot = SimpleNamespace(fence="fence", fences="fences")
    if waited is not None:
        assert hotpath.wait_fence("dev", slot, 1000) is waited
    if looked is not None:
        assert hotpath.fence_signalled("dev", slot) is looked


@pytest.mark.parametrize("name, make", [
    ("vkWaitForFences", lambda s: hotpath.wait_fence("dev", s, 10)),
    ("vkGetFenceStatus", lambda s: hotpath.fence_signalled("dev", s)),
    ("vkResetFences", lambda s: hotpath.reset_fence("dev", s)),
    ("vkQueueSubmit", lambda s: hotpath.submit("queue", s, [], [])),
])
def test_a_failing_call_is_a_vulkan_error_naming_it(monkeypatch, name, make):
    monkeypatch.setattr(hotpath, "vk", lambda: _fake(-4))  # VK_ERROR_DEVICE_LOST
    slot = SimpleNamespace(fence=vk().ffi.NULL, fences=None, cmds=vk().ffi.NULL)
    with pytest.raises(VulkanError, match=f"^{name} failed: VkErrorDeviceLost$"):
        make(slot)


def test_the_benchmark_prints_both_ways(capsys):
    """benchmarks/submit_overhead.py on lavapipe: the CPU per task through the binding and
    straight, each a positive figure (the benchmark prints them; no timing is asserted)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "submit_overhead.py"
    spec = importlib.util.spec_from_file_location("submit_overhead", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--tasks", "20"]) == 0
    printed = capsys.readouterr().out
    for name in ("through the binding", "straight (hotpath.py)"):
        line = next(line for line in printed.splitlines() if name in line)
        assert float(line.split()[-2]) > 0


@pytest.mark.parametrize("code, words", [(-1000069000, "VK_ERROR_OUT_OF_POOL_MEMORY"),
                                         (-1234567, "VkResult -1234567")])
def test_a_result_the_binding_does_not_know_is_named_by_call_as_by_the_hot_path(code, words):
    """The binding raises KeyError for a result missing from its table: `call` names it as
    `result_name` (and so the hot path) does."""
    from mgpusim.real.vulkan.vk_errors import call, result_name

    def unknown() -> None:
        raise KeyError(code)
    with pytest.raises(VulkanError, match=words) as info:
        call("vkSomething", unknown)
    assert "vkSomething" in str(info.value) and result_name(code) == words
