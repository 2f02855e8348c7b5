"""VkInstance creation, physical-device discovery and the validation-layer messenger.

Why an `Instance` class: on lavapipe every simulated GPU needs its *own* VkInstance (its own
rasterizer thread pool, docs/vulkan.md: binding traps), with LP_NUM_THREADS set while its physical device is
created. The validation layer is switched on by `validation=True` or MGPUSIM_VK_VALIDATION=1 (the
tests set it); every error it reports is collected in :data:`VALIDATION_MESSAGES`.
"""
from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import Any

from mgpusim.model.errors import DependencyError
from mgpusim.real.host import priority as host_priority
from mgpusim.real.host.heap import keep_heap
from mgpusim.real.vulkan.vk_errors import APT_LAYERS, APT_RUNTIME, VulkanError, call, vk

VALIDATION_LAYER = "VK_LAYER_KHRONOS_validation"
EXT_CALIBRATED = ("VK_KHR_calibrated_timestamps", "VK_EXT_calibrated_timestamps")
EXT_HOST_MEMORY = "VK_EXT_external_memory_host"

#: (severity, message) of every validation warning/error since start (all instances).
VALIDATION_MESSAGES: list[tuple[str, str]] = []
_env_lock = threading.Lock()


def validation_errors() -> list[str]:
    """Messages of severity ERROR reported by the validation layer so far."""
    return [m for sev, m in VALIDATION_MESSAGES if sev == "error"]


def _messenger_callback(severity: int, types: int, data: Any, user: Any) -> int:
    lib = vk().lib
    if severity & lib.VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT:
        sev = "error"
    elif severity & lib.VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT:
        sev = "warning"
    else:
        return 0
    msg = vk().ffi.string(data.pMessage).decode(errors="replace") if data.pMessage else "?"
    VALIDATION_MESSAGES.append((sev, msg))
    return 0  # VK_FALSE: never abort the call


@dataclass(frozen=True)
class QueueFamilyInfo:
    """One queue family: its index, capabilities and queue count."""

    index: int
    flags: int
    count: int
    timestamp_valid_bits: int

    @property
    def graphics(self) -> bool:
        return bool(self.flags & 1)

    @property
    def compute(self) -> bool:
        return bool(self.flags & 2)

    @property
    def transfer(self) -> bool:  # graphics/compute families implicitly support transfer
        return bool(self.flags & 7)

    @property
    def kind(self) -> str:
        """graphics | compute (async compute) | transfer (copy engine) | other (video...)."""
        if self.graphics:
            return "graphics"
        if self.compute:
            return "compute"
        return "transfer" if self.flags & 4 else "other"


@dataclass(frozen=True)
class PhysicalDeviceInfo:
    """What `mgpusim devices` lists and the machine record stores about one physical device."""

    index: int
    name: str
    device_type: str
    vendor_id: int
    driver_name: str
    driver_info: str
    driver_version: int
    api_version: str
    timestamp_period: float
    queue_families: tuple[QueueFamilyInfo, ...]
    extensions: frozenset[str] = field(repr=False)

    @property
    def is_lavapipe(self) -> bool:
        return self.driver_name.lower() in ("llvmpipe", "lavapipe") or "llvmpipe" in self.name

    @property
    def calibrated_timestamps(self) -> str | None:
        """The calibrated-timestamps extension to use (KHR preferred), or None."""
        return next((e for e in EXT_CALIBRATED if e in self.extensions), None)

    @property
    def external_memory_host(self) -> bool:
        return EXT_HOST_MEMORY in self.extensions


_TYPES = {0: "other", 1: "integrated", 2: "discrete", 3: "virtual", 4: "cpu"}


def _describe(index: int, handle: Any) -> PhysicalDeviceInfo:
    v = vk()
    drv = v.VkPhysicalDeviceDriverProperties(
        sType=v.lib.VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES)
    props2 = v.VkPhysicalDeviceProperties2(
        sType=v.lib.VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, pNext=drv)
    call("vkGetPhysicalDeviceProperties2", v.vkGetPhysicalDeviceProperties2, handle, props2)
    props = call("vkGetPhysicalDeviceProperties", v.vkGetPhysicalDeviceProperties, handle)
    fams = call("vkGetPhysicalDeviceQueueFamilyProperties",
                v.vkGetPhysicalDeviceQueueFamilyProperties, handle)
    exts = call("vkEnumerateDeviceExtensionProperties",
                v.vkEnumerateDeviceExtensionProperties, handle, None)
    api = props.apiVersion
    return PhysicalDeviceInfo(
        index=index, name=props.deviceName, device_type=_TYPES.get(props.deviceType, "?"),
        vendor_id=props.vendorID, driver_name=v.ffi.string(drv.driverName).decode(),
        driver_info=v.ffi.string(drv.driverInfo).decode(), driver_version=props.driverVersion,
        api_version=f"{api >> 22}.{(api >> 12) & 0x3FF}.{api & 0xFFF}",
        timestamp_period=float(props.limits.timestampPeriod),
        queue_families=tuple(QueueFamilyInfo(i, f.queueFlags, f.queueCount, f.timestampValidBits)
                             for i, f in enumerate(fams)),
        extensions=frozenset(e.extensionName for e in exts))


def validation_wanted(validation: bool | None) -> bool:
    if validation is not None:
        return validation
    return os.environ.get("MGPUSIM_VK_VALIDATION", "") not in ("", "0")


class Instance:
    """One VkInstance with its physical devices (and, if asked, the validation messenger).

    `lp_num_threads` sets LP_NUM_THREADS while the instance and its physical devices are
    created, so lavapipe sizes this instance's rasterizer pool (ignored by other drivers).
    """

    def __init__(self, *, validation: bool | None = None, lp_num_threads: int | None = None):
        v = vk()
        keep_heap()  # before the driver allocates: see mgpusim.real.host.heap
        self.validation = validation_wanted(validation)
        self.lp_num_threads = lp_num_threads
        layers: list[str] = []
        extensions: list[str] = []
        if self.validation:
            available = {p.layerName for p in call("vkEnumerateInstanceLayerProperties",
                                                   v.vkEnumerateInstanceLayerProperties)}
            if VALIDATION_LAYER not in available:
                raise DependencyError(f"the Vulkan validation layer is missing; install it "
                                      f"with: {APT_LAYERS}")
            layers.append(VALIDATION_LAYER)
            extensions.append("VK_EXT_debug_utils")
        self._app = v.VkApplicationInfo(pApplicationName="mgpusim", pEngineName="mgpusim",
                                        apiVersion=v.VK_MAKE_VERSION(1, 2, 0))
        self._layers, self._extensions = layers, extensions
        info = v.VkInstanceCreateInfo(pApplicationInfo=self._app, ppEnabledLayerNames=layers,
                                      ppEnabledExtensionNames=extensions)
        threads_before = host_priority.snapshot()
        with _env_lock:
            old = os.environ.get("LP_NUM_THREADS")
            if lp_num_threads is not None:
                os.environ["LP_NUM_THREADS"] = str(lp_num_threads)
            try:
                try:
                    self.handle = v.vkCreateInstance(info, None)
                except (v.VkErrorIncompatibleDriver, v.VkErrorInitializationFailed) as exc:
                    raise DependencyError(f"no Vulkan driver found ({type(exc).__name__}); "
                                          f"install lavapipe with: {APT_RUNTIME}") from None
                except v.VkException as exc:
                    raise VulkanError("vkCreateInstance", type(exc).__name__) from None
                self._messenger = None
                try:  # from here on a failure destroys the instance it made
                    self._messenger = self._create_messenger() if self.validation else None
                    handles = call("vkEnumeratePhysicalDevices", v.vkEnumeratePhysicalDevices,
                                   self.handle)
                except BaseException:
                    self.close()
                    raise
            finally:
                if lp_num_threads is not None:
                    if old is None:
                        os.environ.pop("LP_NUM_THREADS", None)
                    else:
                        os.environ["LP_NUM_THREADS"] = old
        try:
            if not handles:
                raise DependencyError(f"Vulkan found no device; install lavapipe with: {APT_RUNTIME}")
            self.physical_handles = list(handles)
            self.devices = [_describe(i, h) for i, h in enumerate(handles)]
            if any(d.is_lavapipe for d in self.devices):
                host_priority.promote_new(threads_before)
        except BaseException:
            self.close()
            raise

    def _create_messenger(self) -> Any:
        v = vk()
        lib = v.lib
        self._messenger_info = v.VkDebugUtilsMessengerCreateInfoEXT(
            sType=lib.VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT,
            messageSeverity=(lib.VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT
                             | lib.VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT),
            messageType=(lib.VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT
                         | lib.VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT),
            # performance warnings left out: GENERAL layouts are a deliberate choice (memory.py)
            pfnUserCallback=_messenger_callback)
        create = call("vkGetInstanceProcAddr", v.vkGetInstanceProcAddr, self.handle,
                      "vkCreateDebugUtilsMessengerEXT")
        return call("vkCreateDebugUtilsMessengerEXT", create, self.handle,
                    self._messenger_info, None)

    def proc(self, name: str) -> Any:
        """An instance-level extension function (VulkanError if the driver lacks it)."""
        return call("vkGetInstanceProcAddr", vk().vkGetInstanceProcAddr, self.handle, name)

    def close(self) -> None:
        """Destroy the messenger and the instance (all devices must be closed first)."""
        v = vk()
        if getattr(self, "handle", None) is None:
            return
        if self._messenger is not None:
            self.proc("vkDestroyDebugUtilsMessengerEXT")(self.handle, self._messenger, None)
            self._messenger = None
        v.vkDestroyInstance(self.handle, None)
        self.handle = None

    def __enter__(self) -> "Instance":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
