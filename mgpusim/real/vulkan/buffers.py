"""Buffers and images with their memory, created so that queue families can share them.

Why: the runner moves one resource between a graphics queue and a transfer queue of the same
device. Resources are created with VK_SHARING_MODE_CONCURRENT over the device's families (no
ownership-transfer barriers to get wrong) and images live in VK_IMAGE_LAYOUT_GENERAL, so a pass
or a copy can be recorded on any queue in any order with plain memory barriers.
"""
from __future__ import annotations

from typing import Any, Callable, Protocol

import numpy as np

from mgpusim.model.errors import InputError
from mgpusim.real.vulkan.vk_errors import call, vk


class Gpu(Protocol):
    """What a buffer or image needs of its GPU (:class:`mgpusim.real.vulkan.device.Gpu`), named
    here because the device module creates buffers: importing it back would be a cycle."""

    name: str
    device: Any
    memory_properties: Any
    family_indices: list[int]

    def run(self, queue: Any, record: Callable[[Any], None], label: str = "") -> Any: ...

COLOR_FORMAT = "R8G8B8A8_UNORM"
DEPTH_FORMAT = "D16_UNORM"
_BYTES_PER_PIXEL = {COLOR_FORMAT: 4, DEPTH_FORMAT: 2}


def _memory_type(gpu: Gpu, type_bits: int, host_visible: bool) -> int:
    """Index of a memory type: host-visible+coherent (preferring cached) or device-local."""
    v = vk()
    props = gpu.memory_properties
    want = (v.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | v.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
            if host_visible else v.VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT)
    prefer = v.VK_MEMORY_PROPERTY_HOST_CACHED_BIT if host_visible else 0
    candidates = [i for i in range(props.memoryTypeCount)
                  if type_bits & (1 << i) and props.memoryTypes[i].propertyFlags & want == want]
    if not candidates:
        raise InputError(f"{gpu.name}: no memory type with flags {want:#x}")
    preferred = [i for i in candidates if props.memoryTypes[i].propertyFlags & prefer]
    return (preferred or candidates)[0]


def _allocate(gpu: Gpu, requirements: Any, host_visible: bool) -> Any:
    v = vk()
    info = v.VkMemoryAllocateInfo(
        allocationSize=requirements.size,
        memoryTypeIndex=_memory_type(gpu, requirements.memoryTypeBits, host_visible))
    return call("vkAllocateMemory", v.vkAllocateMemory, gpu.device, info, None)


def _sharing(gpu: Gpu) -> tuple[int, list[int]]:
    v = vk()
    families = gpu.family_indices
    if len(families) > 1:
        return v.VK_SHARING_MODE_CONCURRENT, families
    return v.VK_SHARING_MODE_EXCLUSIVE, []


class Buffer:
    """A VkBuffer; `host_visible` ones are persistently mapped and exposed as `.array` (uint8)."""

    def __init__(self, gpu: Gpu, size: int, *, host_visible: bool, usage: int | None = None):
        v = vk()
        if size <= 0:
            raise InputError(f"buffer size must be positive, got {size}")
        self.gpu, self.size, self.host_visible = gpu, int(size), host_visible
        if usage is None:
            usage = (v.VK_BUFFER_USAGE_TRANSFER_SRC_BIT | v.VK_BUFFER_USAGE_TRANSFER_DST_BIT
                     | v.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | v.VK_BUFFER_USAGE_VERTEX_BUFFER_BIT)
        mode, families = _sharing(gpu)
        info = v.VkBufferCreateInfo(size=self.size, usage=usage, sharingMode=mode,
                                    queueFamilyIndexCount=len(families),
                                    pQueueFamilyIndices=families or None)
        self.memory: Any = None
        self.array: np.ndarray | None = None
        self._mapped = False
        self.handle = call("vkCreateBuffer", v.vkCreateBuffer, gpu.device, info, None)
        try:  # a failure part-way destroys what was made
            req = v.vkGetBufferMemoryRequirements(gpu.device, self.handle)
            self.memory = _allocate(gpu, req, host_visible)
            call("vkBindBufferMemory", v.vkBindBufferMemory, gpu.device, self.handle, self.memory, 0)
            if host_visible:
                ptr = call("vkMapMemory", v.vkMapMemory, gpu.device, self.memory, 0, self.size, 0)
                self._mapped = True
                self.array = np.frombuffer(ptr, dtype=np.uint8, count=self.size)
        except BaseException:
            self.destroy()
            raise

    def view(self, dtype: Any) -> np.ndarray:
        """The mapped memory as an array of `dtype` (host-visible buffers only)."""
        if self.array is None:
            raise InputError("buffer is not host-visible")
        return self.array.view(dtype)

    def destroy(self) -> None:
        v = vk()
        if self.handle is None:
            return
        self.array = None
        if self._mapped:
            v.vkUnmapMemory(self.gpu.device, self.memory)
            self._mapped = False
        v.vkDestroyBuffer(self.gpu.device, self.handle, None)
        if self.memory is not None:
            v.vkFreeMemory(self.gpu.device, self.memory, None)
        self.handle = self.memory = None


class Image:
    """A 2D device-local image (RGBA8 colour or D16 depth) with a view, kept in GENERAL layout."""

    def __init__(self, gpu: Gpu, width: int, height: int, fmt: str = COLOR_FORMAT):
        v = vk()
        if width <= 0 or height <= 0:
            raise InputError(f"image size must be positive, got {width}x{height}")
        self.gpu, self.width, self.height, self.format_name = gpu, int(width), int(height), fmt
        self.format = getattr(v, f"VK_FORMAT_{fmt}")
        depth = fmt == DEPTH_FORMAT
        self.aspect = v.VK_IMAGE_ASPECT_DEPTH_BIT if depth else v.VK_IMAGE_ASPECT_COLOR_BIT
        attach = (v.VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT if depth
                  else v.VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT)
        usage = (attach | v.VK_IMAGE_USAGE_SAMPLED_BIT | v.VK_IMAGE_USAGE_TRANSFER_SRC_BIT
                 | v.VK_IMAGE_USAGE_TRANSFER_DST_BIT)
        mode, families = _sharing(gpu)
        extent = v.VkExtent3D(width=self.width, height=self.height, depth=1)
        info = v.VkImageCreateInfo(
            imageType=v.VK_IMAGE_TYPE_2D, format=self.format, extent=extent, mipLevels=1,
            arrayLayers=1, samples=v.VK_SAMPLE_COUNT_1_BIT, tiling=v.VK_IMAGE_TILING_OPTIMAL,
            usage=usage, sharingMode=mode, queueFamilyIndexCount=len(families),
            pQueueFamilyIndices=families or None, initialLayout=v.VK_IMAGE_LAYOUT_UNDEFINED)
        self.memory: Any = None
        self.view: Any = None
        self.handle = call("vkCreateImage", v.vkCreateImage, gpu.device, info, None)
        try:  # a failure part-way destroys what was made
            req = v.vkGetImageMemoryRequirements(gpu.device, self.handle)
            self.memory = _allocate(gpu, req, host_visible=False)
            call("vkBindImageMemory", v.vkBindImageMemory, gpu.device, self.handle, self.memory, 0)
            self.range = v.VkImageSubresourceRange(aspectMask=self.aspect, baseMipLevel=0,
                                                   levelCount=1, baseArrayLayer=0, layerCount=1)
            view_info = v.VkImageViewCreateInfo(image=self.handle, viewType=v.VK_IMAGE_VIEW_TYPE_2D,
                                                format=self.format, subresourceRange=self.range)
            self.view = call("vkCreateImageView", v.vkCreateImageView, gpu.device, view_info, None)
            gpu.run("graphics", self._to_general)
        except BaseException:
            self.destroy()
            raise

    @property
    def bytes(self) -> int:
        return self.width * self.height * _BYTES_PER_PIXEL[self.format_name]

    def _to_general(self, cmd: Any) -> None:
        v = vk()
        barrier = v.VkImageMemoryBarrier(
            srcAccessMask=0, dstAccessMask=v.VK_ACCESS_MEMORY_READ_BIT | v.VK_ACCESS_MEMORY_WRITE_BIT,
            oldLayout=v.VK_IMAGE_LAYOUT_UNDEFINED, newLayout=v.VK_IMAGE_LAYOUT_GENERAL,
            srcQueueFamilyIndex=v.VK_QUEUE_FAMILY_IGNORED, dstQueueFamilyIndex=v.VK_QUEUE_FAMILY_IGNORED,
            image=self.handle, subresourceRange=self.range)
        barriers = [barrier]
        v.vkCmdPipelineBarrier(cmd, v.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
                               v.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 0, None, 0, None,
                               1, barriers)

    def region(self, buffer_offset: int = 0) -> Any:
        """A VkBufferImageCopy covering the whole image (tightly packed buffer)."""
        v = vk()
        layers = v.VkImageSubresourceLayers(aspectMask=self.aspect, mipLevel=0, baseArrayLayer=0,
                                            layerCount=1)
        return v.VkBufferImageCopy(bufferOffset=buffer_offset, bufferRowLength=0,
                                   bufferImageHeight=0, imageSubresource=layers,
                                   imageOffset=v.VkOffset3D(x=0, y=0, z=0),
                                   imageExtent=v.VkExtent3D(width=self.width, height=self.height,
                                                            depth=1))

    def destroy(self) -> None:
        v = vk()
        if self.handle is None:
            return
        if self.view is not None:
            v.vkDestroyImageView(self.gpu.device, self.view, None)
        v.vkDestroyImage(self.gpu.device, self.handle, None)
        if self.memory is not None:
            v.vkFreeMemory(self.gpu.device, self.memory, None)
        self.handle = self.memory = self.view = None
