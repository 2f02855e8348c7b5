"""Print the Vulkan physical-device groups the driver exposes (vkEnumeratePhysicalDeviceGroups).

Why: the schedules' peer paths (XR `path = "group"`, AFR/XR copies between GPUs without host
memory) need a device group of two or more physical GPUs; `mgpusim devices` lists devices, not
groups. Run on the device machine: `python3 tools/nvidia/device_groups.py`.
"""
from __future__ import annotations

import vulkan as vk


def main() -> None:
    app = vk.VkApplicationInfo(sType=vk.VK_STRUCTURE_TYPE_APPLICATION_INFO,
                               pApplicationName="groups", apiVersion=vk.VK_MAKE_VERSION(1, 1, 0))
    inst = vk.vkCreateInstance(vk.VkInstanceCreateInfo(
        sType=vk.VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO, pApplicationInfo=app), None)
    try:
        groups = vk.vkEnumeratePhysicalDeviceGroups(inst)
        print(f"{len(groups)} physical-device group(s)")
        for i, g in enumerate(groups):
            names = [vk.vkGetPhysicalDeviceProperties(g.physicalDevices[k]).deviceName
                     for k in range(g.physicalDeviceCount)]
            print(f"  group {i}: {g.physicalDeviceCount} device(s) {names}, "
                  f"subsetAllocation={bool(g.subsetAllocation)}")
    finally:
        vk.vkDestroyInstance(inst, None)


if __name__ == "__main__":
    main()
