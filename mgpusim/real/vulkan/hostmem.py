"""One host allocation imported as a VkBuffer by several devices (VK_EXT_external_memory_host).

Why: the five-step pipeline's step 3 (a host-to-host memcpy between two staging buffers) exists
only because a Vulkan memory object belongs to one device. Importing one page-aligned host
allocation into both devices removes it: the secondary's device->host copy writes the memory
the primary's host->device copy reads (the thesis's proposed further work, docs/sources.md: the five-step pipeline).

Lifetime: the mmap outlives every imported VkDeviceMemory; `destroy()` frees the buffers on all
devices first, then unmaps.
"""
from __future__ import annotations

import mmap
from typing import TYPE_CHECKING, Sequence

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.real.vulkan.instance import EXT_HOST_MEMORY
from mgpusim.real.vulkan.vk_errors import call, vk

if TYPE_CHECKING:
    from mgpusim.real.vulkan.device import Gpu


def import_alignment(gpu: "Gpu") -> int:
    """minImportedHostPointerAlignment of `gpu` (the import's address and size granularity)."""
    v = vk()
    lib = v.lib
    ext = v.VkPhysicalDeviceExternalMemoryHostPropertiesEXT(
        sType=lib.VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_EXTERNAL_MEMORY_HOST_PROPERTIES_EXT)
    props2 = v.VkPhysicalDeviceProperties2(
        sType=lib.VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, pNext=ext)
    call("vkGetPhysicalDeviceProperties2", v.vkGetPhysicalDeviceProperties2, gpu.physical, props2)
    return int(ext.minImportedHostPointerAlignment)


class ImportedBuffer:
    """A VkBuffer of one device bound to imported host memory; duck-types memory.Buffer."""

    array: np.ndarray | None  # None once destroyed, as memory.Buffer's

    def __init__(self, gpu: "Gpu", address: int, size: int, array: np.ndarray):
        v = vk()
        lib = v.lib
        self.gpu, self.size, self.array, self.host_visible = gpu, size, array, True
        handle_type = lib.VK_EXTERNAL_MEMORY_HANDLE_TYPE_HOST_ALLOCATION_BIT_EXT
        ext_info = v.VkExternalMemoryBufferCreateInfo(
            sType=lib.VK_STRUCTURE_TYPE_EXTERNAL_MEMORY_BUFFER_CREATE_INFO, handleTypes=handle_type)
        usage = v.VK_BUFFER_USAGE_TRANSFER_SRC_BIT | v.VK_BUFFER_USAGE_TRANSFER_DST_BIT
        families = gpu.family_indices
        mode = v.VK_SHARING_MODE_CONCURRENT if len(families) > 1 else v.VK_SHARING_MODE_EXCLUSIVE
        fams = families if len(families) > 1 else []
        info = v.VkBufferCreateInfo(pNext=ext_info, size=size, usage=usage, sharingMode=mode,
                                    queueFamilyIndexCount=len(fams), pQueueFamilyIndices=fams or None)
        self.handle = call("vkCreateBuffer", v.vkCreateBuffer, gpu.device, info, None)
        self.memory = None
        try:
            pointer = v.ffi.cast("void *", address)
            props = v.VkMemoryHostPointerPropertiesEXT(
                sType=lib.VK_STRUCTURE_TYPE_MEMORY_HOST_POINTER_PROPERTIES_EXT)
            call("vkGetMemoryHostPointerPropertiesEXT",
                 gpu.proc("vkGetMemoryHostPointerPropertiesEXT"), gpu.device, handle_type,
                 pointer, props)
            req = v.vkGetBufferMemoryRequirements(gpu.device, self.handle)
            bits = int(props.memoryTypeBits) & int(req.memoryTypeBits)
            if not bits:
                raise InputError(f"{gpu.name}: no memory type can import host memory for a buffer")
            type_index = (bits & -bits).bit_length() - 1
            import_info = v.VkImportMemoryHostPointerInfoEXT(
                sType=lib.VK_STRUCTURE_TYPE_IMPORT_MEMORY_HOST_POINTER_INFO_EXT,
                handleType=handle_type, pHostPointer=pointer)
            alloc = v.VkMemoryAllocateInfo(pNext=import_info, allocationSize=size,
                                           memoryTypeIndex=type_index)
            self.memory = call("vkAllocateMemory", v.vkAllocateMemory, gpu.device, alloc, None)
            call("vkBindBufferMemory", v.vkBindBufferMemory, gpu.device, self.handle,
                 self.memory, 0)
        except BaseException:
            self.destroy()
            raise

    def destroy(self) -> None:
        v = vk()
        if self.handle is None:
            return
        v.vkDestroyBuffer(self.gpu.device, self.handle, None)
        if self.memory is not None:
            v.vkFreeMemory(self.gpu.device, self.memory, None)
        self.handle = self.memory = None
        self.array = None  # a view into the shared mmap: it must go before the mmap can close


class SharedHostMemory:
    """`size` bytes of page-aligned host memory, imported into every GPU of `gpus`.

    `.array` is the memory as uint8 (numpy); `.buffer(gpu)` the ImportedBuffer of one device.
    """

    array: np.ndarray | None  # None once destroyed
    _whole: np.ndarray | None

    def __init__(self, size: int, gpus: Sequence["Gpu"]):
        if size <= 0:
            raise InputError(f"shared host memory size must be positive, got {size}")
        missing = [g.name for g in gpus if EXT_HOST_MEMORY not in g.enabled_extensions]
        if missing:
            raise InputError(f"{', '.join(missing)}: the device lacks {EXT_HOST_MEMORY}; run "
                             f"with schedule.host_copy=true instead")
        align = max([mmap.PAGESIZE] + [import_alignment(g) for g in gpus])
        self.size = size
        self.alloc_size = -(-size // align) * align
        self._map = mmap.mmap(-1, self.alloc_size)  # anonymous: page-aligned
        whole = np.frombuffer(self._map, dtype=np.uint8)
        if whole.ctypes.data % align:
            raise InputError(f"host allocation not aligned to {align} bytes")
        array = self.array = whole[:size]
        self._buffers: dict[int, ImportedBuffer] = {}
        try:
            for g in gpus:
                self._buffers[id(g)] = ImportedBuffer(g, whole.ctypes.data, self.alloc_size, array)
        except BaseException:
            self.destroy()
            raise
        self._whole = whole

    def buffer(self, gpu: "Gpu") -> ImportedBuffer:
        return self._buffers[id(gpu)]

    def destroy(self) -> None:
        """Free every device's import, then the host memory."""
        for buf in self._buffers.values():
            buf.destroy()
        self._buffers.clear()
        self.array = None
        self._whole = None
        if getattr(self, "_map", None) is not None:
            try:
                self._map.close()
            except BufferError:  # a numpy view is still alive somewhere: leave it to the GC
                pass
            self._map = None  # type: ignore[assignment]
