"""The validation-layer messenger really catches errors (so the session check means something)."""
from __future__ import annotations

import pytest

from mgpusim.real.vulkan import instance as vkinst
from mgpusim.real.vulkan.vk_errors import vk

pytestmark = pytest.mark.vulkan


def test_messenger_collects_a_deliberate_error(gpu):
    assert gpu.instance.validation
    v = vk()
    before = len(vkinst.VALIDATION_MESSAGES)
    info = v.VkBufferCreateInfo(size=256, usage=0, sharingMode=v.VK_SHARING_MODE_EXCLUSIVE)
    try:
        buf = v.vkCreateBuffer(gpu.device, info, None)  # usage 0 is invalid (VUID ...-usage-...)
        v.vkDestroyBuffer(gpu.device, buf, None)
    finally:
        caught = vkinst.VALIDATION_MESSAGES[before:]
        del vkinst.VALIDATION_MESSAGES[before:]  # expected: keep the session check clean
    assert any(sev == "error" and "usage" in msg for sev, msg in caught), caught
