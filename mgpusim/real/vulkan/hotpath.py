"""The Vulkan calls the runner makes for every task, made straight on the C library.

Why not through the `vulkan` binding like every other call: its wrappers convert each argument
in Python on every call (the function's signature looked up, each handle and list cast to a new
C array) and build a struct field by field through keyword defaults. For a task that is all the
Python there is: submit, fence wait, timestamp read, fence reset. `benchmarks/submit_overhead.py`
times the four calls both ways on one thread: on lavapipe 75-136 us of CPU per task through the
binding, 22-57 us made here (the VM's speed moved between runs). With light 4-GPU frames the
runner's threads kept the interpreter busy for most of the run, and a thread woken by a fence
waited for it (docs/nvidia_h200_x4.md, "The threads wait for the interpreter"): what the
runner spends in Python delays the very hand-offs it measures.

A :class:`Slot` keeps the C arrays its calls pass, made once when the slot is made. Every
function here returns or raises as the binding would: a failing call is a VulkanError naming it.
cffi releases the interpreter lock during each call, as the binding's calls do.

Where a slot has `stamps` (on lavapipe), its command buffer copies the two timestamps into that
mapped memory itself, and :func:`read_ticks` reads them from there with no Vulkan call. Why:
lavapipe's vkGetQueryPoolResults waits for the whole device to go idle before it reads (Mesa
22.3's `lvp_GetQueryPoolResults` calls DeviceWaitIdle first, whatever the flags), so a GPU kept
busy frame after frame left its reap thread blocked for many frames. Its slots did not come
back, and the submit thread recorded a new command buffer for 15-35 % of the tasks of a light
4-GPU sort-first run: Python work on the critical path of the hand-offs being measured.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

from mgpusim.real.vulkan.vk_errors import VulkanError, result_name, vk

#: VkResult of success; the other non-negative results the callers get (VK_NOT_READY from a
#: fence look, VK_TIMEOUT from a fence wait) read as "not yet"
SUCCESS = 0


@dataclass(eq=False)
class Slot:
    """One reusable submission: a command buffer, its fence, its two-timestamp query pool, and
    the C arrays that pass them (`cmds`, `fences`) and receive the timestamps (`ticks`)."""

    cmd: Any
    fence: Any
    pool: Any
    #: where the command buffer copies its two timestamps (a mapped uint64[2]), or None: they
    #: are read from the query pool
    stamps: Any = None
    #: the VkBuffer behind `stamps`, which the command buffer copies the timestamps into
    stamp_buffer: Any = None
    cmds: Any = field(init=False, repr=False)
    fences: Any = field(init=False, repr=False)
    ticks: Any = field(init=False, repr=False)

    def __post_init__(self) -> None:
        ffi = vk().ffi
        self.cmds = ffi.new("VkCommandBuffer[1]", [self.cmd])
        self.fences = ffi.new("VkFence[1]", [self.fence])
        self.ticks = ffi.new("uint64_t[2]")


def _check(name: str, result: int) -> int:
    """`result` if it is success or a status the caller handles; a VulkanError otherwise."""
    if result < 0:
        raise VulkanError(name, result_name(result))
    return result


def submit(queue: Any, slot: Slot, wait: Sequence[Any] = (), signal: Sequence[Any] = ()) -> None:
    """vkQueueSubmit of `slot`'s command buffer, waiting for the semaphore handles `wait` (at
    every stage) and signalling `signal`; the slot's fence signals when it is done."""
    v = vk()
    ffi = v.ffi
    info = ffi.new("VkSubmitInfo*")
    info.sType = v.VK_STRUCTURE_TYPE_SUBMIT_INFO
    info.commandBufferCount = 1
    info.pCommandBuffers = slot.cmds
    if wait:  # the arrays must live until vkQueueSubmit returns: kept in locals
        waits = ffi.new("VkSemaphore[]", list(wait))
        stages = ffi.new("VkPipelineStageFlags[]", [v.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT] * len(wait))
        info.waitSemaphoreCount, info.pWaitSemaphores, info.pWaitDstStageMask = len(wait), waits, stages
    if signal:
        signals = ffi.new("VkSemaphore[]", list(signal))
        info.signalSemaphoreCount, info.pSignalSemaphores = len(signal), signals
    _check("vkQueueSubmit", v.lib.vkQueueSubmit(queue, 1, info, slot.fence))


def wait_fence(device: Any, slot: Slot, timeout_ns: int) -> bool:
    """True once `slot`'s fence signalled, False if `timeout_ns` passed first."""
    result = _check("vkWaitForFences",
                    vk().lib.vkWaitForFences(device, 1, slot.fences, 1, max(0, timeout_ns)))
    return result == SUCCESS


def fence_signalled(device: Any, slot: Slot) -> bool:
    """A look at `slot`'s fence, no wait."""
    return _check("vkGetFenceStatus", vk().lib.vkGetFenceStatus(device, slot.fence)) == SUCCESS


def reset_fence(device: Any, slot: Slot) -> None:
    _check("vkResetFences", vk().lib.vkResetFences(device, 1, slot.fences))


def read_ticks(device: Any, slot: Slot) -> tuple[int, int]:
    """The finished work's two timestamps in device ticks (waits for them to be available):
    from the slot's `stamps` where it has them (its fence must have signalled), else from its
    query pool."""
    if slot.stamps is not None:
        return int(slot.stamps[0]), int(slot.stamps[1])
    v = vk()
    flags = v.VK_QUERY_RESULT_64_BIT | v.VK_QUERY_RESULT_WAIT_BIT
    _check("vkGetQueryPoolResults",
           v.lib.vkGetQueryPoolResults(device, slot.pool, 0, 2, 16, slot.ticks, 8, flags))
    return int(slot.ticks[0]), int(slot.ticks[1])
