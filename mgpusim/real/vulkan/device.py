"""A simulated GPU: one VkDevice with its queues by family, and timestamped submissions.

Why one class: the runner needs, per simulated GPU, "record this on that queue, wait for these
semaphores, signal those, and tell me when it ran on the host clock". `Gpu.submit` does exactly
that: it brackets the recorded work with timestamps (behind full barriers, so the stamps enclose
the work) and returns a :class:`Submission` whose `timestamps_ns()` are time.monotonic_ns()
values. Each queue has a lock: VkQueue and VkCommandPool need external synchronization, and the
runner submits from several Python threads (cffi releases the GIL).
"""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from mgpusim.model.errors import InputError
from mgpusim.real.host import priority as host_priority
from mgpusim.real.vulkan import hotpath
from mgpusim.real.vulkan.buffers import Buffer, Image
from mgpusim.real.vulkan.hotpath import Slot
from mgpusim.real.vulkan.instance import Instance, PhysicalDeviceInfo, QueueFamilyInfo
from mgpusim.real.vulkan.vk_errors import call, vk

Recorder = Callable[[Any], None]
QUEUE_KINDS = ("graphics", "compute", "transfer")
#: a slot's two 64-bit timestamps, copied by its command buffer where the driver's query read
#: would wait for the device to idle (lavapipe; see hotpath)
STAMP_BYTES = 16


@dataclass(eq=False)
class Queue:
    """One VkQueue with its own command pool and a free list of slots (command buffer, fence,
    query pool)."""

    gpu: "Gpu"
    kind: str
    family: QueueFamilyInfo
    index: int
    handle: Any
    pool: Any
    lock: threading.Lock = field(default_factory=threading.Lock)
    free: list[Slot] = field(default_factory=list)
    #: idle slots whose command buffer holds a recording that can be submitted again, by key
    recorded: dict[Any, list[Slot]] = field(default_factory=dict)

    def idle_slots(self) -> list[Slot]:
        return self.free + [s for slots in self.recorded.values() for s in slots]

    @property
    def dedicated(self) -> bool:
        """True when this is its own family (a copy engine / async compute), not graphics."""
        return self.family.kind == self.kind


class Semaphore:
    """A binary VkSemaphore of one device (signal once, wait once)."""

    def __init__(self, gpu: "Gpu"):
        v = vk()
        self.gpu = gpu
        self.handle = call("vkCreateSemaphore", v.vkCreateSemaphore, gpu.device,
                           v.VkSemaphoreCreateInfo(), None)

    def destroy(self) -> None:
        if self.handle is not None:
            vk().vkDestroySemaphore(self.gpu.device, self.handle, None)
            self.handle = None


class Submission:
    """Work submitted on a queue; `wait()` then `timestamps_ns()` gives its host-clock span."""

    def __init__(self, queue: Queue, slot: Slot, label: str, key: Any = None):
        self.queue, self.label, self.key = queue, label, key
        self._slot: Slot | None = slot
        self._ticks: tuple[int, int] | None = None
        self._finished = False
        #: held by the one thread that reads the timestamps and recycles the slot
        self._read_lock = threading.Lock()
        #: held while the slot is looked up (a waiter taking the watch, `poll`'s look at the
        #: fence) and while the fence is reset and the slot recycled: vkResetFences needs the
        #: fence to itself, and a recycled slot belongs to the next submission. Not held during
        #: the fence wait (`_watched` keeps the slot) nor while the timestamps are read: that
        #: read can block for milliseconds on lavapipe.
        self._slot_lock = threading.Lock()
        #: True while one thread is inside vkWaitForFences on this fence for all the others
        self._watched = False
        #: notified when the watcher leaves the fence wait (finished or timed out); made only
        #: when a second thread has to wait for the watcher (a Condition is Python to build,
        #: and most submissions have one waiter)
        self._changed: threading.Condition | None = None

    def finished(self, timeout_ns: int) -> bool:
        """True once the work has finished, waiting at most `timeout_ns`; any thread may ask,
        and none of them reads the timestamps.

        Why apart from `wait()`: on lavapipe reading a query pool's results blocks until the
        queue is idle, so a thread that waited for task A by reading A's timestamps woke only
        when the work queued behind A was done too (measured: 5-13 ms late).

        Why one thread waits on the fence and the others wait for it in Python: only that one
        calls the driver, and the slot is recycled once it has left the wait. On 4x H200
        (driver 580) this, one waiter at a time behind a lock, and every waiter inside
        vkWaitForFences at once gave alike frame times; what delays a woken thread there is
        the interpreter, busy with the other runner threads (2026-11-27,
        data/nvidia/h200_x4/waits_2026-11-27)."""
        if timeout_ns <= 0:
            return self.poll()
        deadline = time.monotonic_ns() + timeout_ns
        with self._slot_lock:
            while self._watched and not self._finished:
                left = deadline - time.monotonic_ns()
                if left <= 0:
                    return False
                self._condition().wait(left / 1e9)
            if self._finished or self._slot is None:
                return True
            self._watched = True
            slot = self._slot
        signalled = False
        try:
            signalled = hotpath.wait_fence(self.queue.gpu.device, slot,
                                           deadline - time.monotonic_ns())
        finally:
            with self._slot_lock:
                self._watched = False
                self._finished = self._finished or signalled
                if self._changed is not None:
                    self._changed.notify_all()
        return signalled

    def _condition(self) -> threading.Condition:
        """The watcher's Condition, made on first need; call with `_slot_lock` held."""
        if self._changed is None:
            self._changed = threading.Condition(self._slot_lock)
        return self._changed

    def done(self) -> bool:
        """True once the GPU finished (a look at the fence, no wait)."""
        return self.poll()

    def poll(self) -> bool:
        """True if the work has finished, without waiting for the fence; at most for the
        microseconds of a fence reset. A slot already recycled was finished."""
        with self._slot_lock:
            if self._finished or self._slot is None:
                return True
            self._finished = hotpath.fence_signalled(self.queue.gpu.device, self._slot)
            return self._finished

    def wait(self, timeout_ns: int = 60_000_000_000) -> "Submission":
        """Block until the work finished; reads the timestamps and recycles the slot."""
        if self._ticks is not None:
            return self
        if not self.finished(timeout_ns):
            raise vk().VkTimeout(f"{self.label} did not finish within {timeout_ns} ns")
        with self._read_lock:
            if self._ticks is None:  # another thread may have read them meanwhile
                ticks = self._read_ticks()
                with self._slot_lock:  # the fence is signalled: a watcher returns at once
                    if self._watched:
                        self._condition().wait_for(lambda: not self._watched)
                    self._recycle()
                    self._ticks = ticks
        return self

    def _read_ticks(self) -> tuple[int, int]:
        """The finished work's two timestamps, in device ticks."""
        assert self._slot is not None
        return hotpath.read_ticks(self.queue.gpu.device, self._slot)

    def _recycle(self) -> None:
        """Reset the fence and give the slot back to its queue, for the next submission."""
        assert self._slot is not None
        hotpath.reset_fence(self.queue.gpu.device, self._slot)
        with self.queue.lock:
            if self.key is None:
                self.queue.free.append(self._slot)
            else:
                self.queue.recorded.setdefault(self.key, []).append(self._slot)
        self._slot = None

    def raw_ticks(self) -> tuple[int, int]:
        """Device timestamp ticks (start, end)."""
        self.wait()
        assert self._ticks is not None
        return self._ticks

    def timestamps_ns(self) -> tuple[int, int]:
        """(start, end) on the host clock, time.monotonic_ns() based."""
        start, end = self.raw_ticks()
        clock = self.queue.gpu.clock
        return clock.to_host_ns(start), clock.to_host_ns(end)

    @property
    def duration_ns(self) -> int:
        start, end = self.raw_ticks()
        return int(round((end - start) * self.queue.gpu.info.timestamp_period))


class Gpu:
    """One simulated GPU: a VkDevice on `instance.physical_handles[physical_index]`.

    `queues` maps graphics/compute/transfer to a Queue; compute and transfer fall back to the
    graphics queue when the device has no dedicated family (lavapipe has one family).
    """

    def __init__(self, instance: Instance, physical_index: int = 0, name: str = "gpu0", *,
                 owns_instance: bool = False):
        v = vk()
        if not 0 <= physical_index < len(instance.devices):
            raise InputError(f"no physical device {physical_index}; found "
                             f"{len(instance.devices)}")
        self.instance, self.name, self.owns_instance = instance, name, owns_instance
        self.physical = instance.physical_handles[physical_index]
        #: which physical device of the instance (several simulated GPUs may share one)
        self.physical_index = physical_index
        self.info: PhysicalDeviceInfo = instance.devices[physical_index]
        fams = self.info.queue_families
        chosen: dict[str, QueueFamilyInfo] = {}
        for kind in QUEUE_KINDS:
            fam = next((f for f in fams if f.kind == kind and f.timestamp_valid_bits), None)
            if fam is not None:
                chosen[kind] = fam
        if "graphics" not in chosen:
            raise InputError(f"{self.info.name}: no graphics queue family with timestamps")
        self.family_indices = sorted({f.index for f in chosen.values()})
        prio = [1.0]
        qinfos = [v.VkDeviceQueueCreateInfo(queueFamilyIndex=i, queueCount=1,
                                            pQueuePriorities=prio) for i in self.family_indices]
        # VK_EXT_external_memory_host: the runner's variant without the host-to-host copy
        host_mem = "VK_EXT_external_memory_host" if self.info.external_memory_host else None
        self.enabled_extensions = [e for e in (self.info.calibrated_timestamps, host_mem) if e]
        exts = self.enabled_extensions
        info = v.VkDeviceCreateInfo(queueCreateInfoCount=len(qinfos), pQueueCreateInfos=qinfos,
                                    ppEnabledExtensionNames=exts or None)
        self.queues: dict[str, Queue] = {}
        self._semaphores: list[Semaphore] = []
        #: the slots' timestamp targets (lavapipe), destroyed with the device
        self._stamp_buffers: list[Buffer] = []
        threads_before = host_priority.snapshot() if self.info.is_lavapipe else None
        self.device = call("vkCreateDevice", v.vkCreateDevice, self.physical, info, None)
        host_priority.promote_new(threads_before)  # its queue thread, rasterizers, compute pool
        try:  # from here on a failure destroys the device (and pools) it made
            self._finish_setup(chosen)
        except BaseException:
            self.close()
            raise

    def _finish_setup(self, chosen: dict[str, Any]) -> None:
        """Queues with their command pools, then the clock (which needs a working Gpu)."""
        v = vk()
        self.memory_properties = v.vkGetPhysicalDeviceMemoryProperties(self.physical)
        by_family: dict[int, Queue] = {}
        for kind in QUEUE_KINDS:
            fam = chosen.get(kind, chosen["graphics"])
            if fam.index not in by_family:
                pool_info = v.VkCommandPoolCreateInfo(
                    flags=v.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT,
                    queueFamilyIndex=fam.index)
                pool = call("vkCreateCommandPool", v.vkCreateCommandPool, self.device,
                            pool_info, None)
                handle = v.vkGetDeviceQueue(self.device, fam.index, 0)
                by_family[fam.index] = Queue(self, fam.kind, fam, 0, handle, pool)
            self.queues[kind] = by_family[fam.index]
        from mgpusim.real.vulkan.timestamps import calibrate  # noqa: PLC0415 - needs a working Gpu
        self.clock = calibrate(self)

    # -- queues and sync ---------------------------------------------------------------------
    def queue(self, kind: str | Queue) -> Queue:
        if isinstance(kind, Queue):
            return kind
        if kind not in self.queues:
            raise InputError(f"unknown queue {kind!r}; expected one of {', '.join(QUEUE_KINDS)}")
        return self.queues[kind]

    def has_dedicated(self, kind: str) -> bool:
        """True if `kind` (compute/transfer) has its own queue family on this device."""
        return self.queue(kind).family.kind == kind

    def semaphore(self) -> Semaphore:
        sem = Semaphore(self)
        self._semaphores.append(sem)
        return sem

    def proc(self, name: str) -> Any:
        return call("vkGetDeviceProcAddr", vk().vkGetDeviceProcAddr, self.device, name)

    # -- resources ---------------------------------------------------------------------------
    def buffer(self, size: int, *, host_visible: bool, usage: int | None = None) -> Buffer:
        return Buffer(self, size, host_visible=host_visible, usage=usage)

    def image(self, width: int, height: int, fmt: str = "R8G8B8A8_UNORM") -> Image:
        return Image(self, width, height, fmt)

    # -- submission --------------------------------------------------------------------------
    @property
    def cpu_threads(self) -> int | None:
        """Rasterizer threads of a lavapipe GPU (LP_NUM_THREADS, default one per CPU); None
        for a real GPU."""
        if not self.info.is_lavapipe:
            return None
        from_env = os.environ.get("LP_NUM_THREADS", "")
        return (self.instance.lp_num_threads or (int(from_env) if from_env.isdigit() else 0)
                or os.cpu_count() or 1)

    def _slot(self, q: Queue) -> Slot:
        if q.free:
            return q.free.pop()
        v = vk()
        alloc = v.VkCommandBufferAllocateInfo(commandPool=q.pool,
                                              level=v.VK_COMMAND_BUFFER_LEVEL_PRIMARY,
                                              commandBufferCount=1)
        cmd = call("vkAllocateCommandBuffers", v.vkAllocateCommandBuffers, self.device, alloc)[0]
        fence = call("vkCreateFence", v.vkCreateFence, self.device, v.VkFenceCreateInfo(), None)
        qp_info = v.VkQueryPoolCreateInfo(queryType=v.VK_QUERY_TYPE_TIMESTAMP, queryCount=2)
        pool = call("vkCreateQueryPool", v.vkCreateQueryPool, self.device, qp_info, None)
        slot = Slot(cmd, fence, pool)
        if self.info.is_lavapipe:  # its query read waits for the device to idle (hotpath)
            buffer = Buffer(self, STAMP_BYTES, host_visible=True, usage=v.VK_BUFFER_USAGE_TRANSFER_DST_BIT)
            self._stamp_buffers.append(buffer)
            slot.stamps = buffer.view("<u8")
            slot.stamp_buffer = buffer.handle
        return slot

    def submit(self, queue: str | Queue, record: Recorder, *, wait: Sequence[Semaphore] = (),
               signal: Sequence[Semaphore] = (), label: str = "", key: Any = None) -> Submission:
        """Record `record(cmd)` between two timestamps and submit it on `queue`.

        `key`: work that records the same commands every time it is submitted with this key.
        Its command buffers are recorded once per slot and submitted again as they come back
        (as a renderer submits pre-recorded command buffers), so repeated submissions cost no
        recording on the host."""
        q = self.queue(queue)
        with q.lock:
            ready = q.recorded.get(key) if key is not None else None
            if ready:
                slot = ready.pop()
            else:
                slot = self._slot(q)
                self._record(slot, record, once=key is None)
            hotpath.submit(q.handle, slot, [s.handle for s in wait], [s.handle for s in signal])
        return Submission(q, slot, label, key)

    @staticmethod
    def _record(slot: Slot, record: Recorder, once: bool) -> None:
        """`record(cmd)` between two timestamps, each behind a full barrier."""
        v = vk()
        cmd, pool = slot.cmd, slot.pool
        all_cmds = v.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT
        mem = v.VK_ACCESS_MEMORY_READ_BIT | v.VK_ACCESS_MEMORY_WRITE_BIT
        barriers = [v.VkMemoryBarrier(srcAccessMask=mem, dstAccessMask=mem)]
        flags = v.VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT if once else 0
        call("vkBeginCommandBuffer", v.vkBeginCommandBuffer, cmd,
             v.VkCommandBufferBeginInfo(flags=flags))
        v.vkCmdResetQueryPool(cmd, pool, 0, 2)
        v.vkCmdPipelineBarrier(cmd, all_cmds, all_cmds, 0, 1, barriers, 0, None, 0, None)
        v.vkCmdWriteTimestamp(cmd, v.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, pool, 0)
        v.vkCmdPipelineBarrier(cmd, all_cmds, all_cmds, 0, 1, barriers, 0, None, 0, None)
        record(cmd)
        v.vkCmdPipelineBarrier(cmd, all_cmds, all_cmds, 0, 1, barriers, 0, None, 0, None)
        v.vkCmdWriteTimestamp(cmd, v.VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, pool, 1)
        if slot.stamps is not None:  # the stamps into mapped memory, for the host to read
            v.vkCmdCopyQueryPoolResults(cmd, pool, 0, 2, slot.stamp_buffer, 0, 8,
                                        v.VK_QUERY_RESULT_64_BIT | v.VK_QUERY_RESULT_WAIT_BIT)
            to_host = [v.VkMemoryBarrier(srcAccessMask=v.VK_ACCESS_TRANSFER_WRITE_BIT,
                                         dstAccessMask=v.VK_ACCESS_HOST_READ_BIT)]
            v.vkCmdPipelineBarrier(cmd, v.VK_PIPELINE_STAGE_TRANSFER_BIT, v.VK_PIPELINE_STAGE_HOST_BIT,
                                   0, 1, to_host, 0, None, 0, None)
        call("vkEndCommandBuffer", v.vkEndCommandBuffer, cmd)

    def take_recorded(self, queue: str | Queue, key: Any, record: Recorder, count: int) -> list[Slot]:
        """`count` idle slots holding `record`'s commands for `key` (recorded now where fewer
        are idle), for a caller that submits, waits and resets them itself: the native runner
        core. They come back with `give_back`."""
        q = self.queue(queue)
        with q.lock:
            slots = q.recorded.pop(key, [])
            try:
                while len(slots) < count:
                    slot = self._slot(q)
                    try:
                        self._record(slot, record, once=False)
                    except BaseException:
                        q.free.append(slot)  # not recorded: the free list records it afresh
                        raise
                    slots.append(slot)
            except BaseException:
                q.recorded[key] = slots  # kept for Gpu.close
                raise
            if len(slots) > count:
                q.recorded[key] = slots[count:]
        return slots[:count]

    def give_back(self, queue: str | Queue, key: Any, slots: Sequence[Slot]) -> None:
        """Slots of `take_recorded`, their fences reset, idle again."""
        q = self.queue(queue)
        with q.lock:
            q.recorded.setdefault(key, []).extend(slots)

    def forget(self, key: Any) -> None:
        """Drop the command buffers recorded for `key` (before the work they draw is destroyed):
        their slots go back to the free list, to be recorded afresh."""
        for q in self.queues.values():
            with q.lock:
                q.free.extend(q.recorded.pop(key, []))

    def run(self, queue: str | Queue, record: Recorder, label: str = "") -> Submission:
        """Submit and wait: for set-up work and measurements."""
        return self.submit(queue, record, label=label).wait()

    def wait_idle(self) -> None:
        call("vkDeviceWaitIdle", vk().vkDeviceWaitIdle, self.device)

    def close(self) -> None:
        """Destroy the device (after its resources), and the instance if this Gpu owns it."""
        v = vk()
        if self.device is None:
            return
        self.wait_idle()
        for sem in self._semaphores:
            sem.destroy()
        for q in {id(q): q for q in self.queues.values()}.values():
            for slot in q.idle_slots():
                v.vkDestroyFence(self.device, slot.fence, None)
                v.vkDestroyQueryPool(self.device, slot.pool, None)
            q.free.clear()
            q.recorded.clear()
            v.vkDestroyCommandPool(self.device, q.pool, None)
        for buffer in self._stamp_buffers:
            buffer.destroy()
        self._stamp_buffers.clear()
        v.vkDestroyDevice(self.device, None)
        self.device = None
        if self.owns_instance:
            self.instance.close()

    def __enter__(self) -> "Gpu":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
