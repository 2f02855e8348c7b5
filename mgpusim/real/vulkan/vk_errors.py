"""Vulkan errors as mgpusim errors, and the one place that imports the `vulkan` binding.

Why: the binding raises bare exception classes (`VkErrorUnknown`) or even `KeyError` for
extension codes it does not know (docs/vulkan.md: binding traps); a user needs the failing call's name, and a
missing loader or driver must read as one line with the command that installs it.
"""
from __future__ import annotations

import shutil
from types import ModuleType
from typing import Any, Callable

from mgpusim.model.errors import DependencyError, MgpusimError

APT_RUNTIME = "sudo apt-get install mesa-vulkan-drivers libvulkan1"
APT_COMPILER = "sudo apt-get install glslc   (or: sudo apt-get install glslang-tools)"
APT_LAYERS = "sudo apt-get install vulkan-validationlayers"
PIP_VULKAN = "pip install 'mgpusim[vulkan]'"

#: Result codes the binding's exception table lacks or gets wrong (from vk.lib at import).
_EXTRA_CODES = {
    -1000069000: "VK_ERROR_OUT_OF_POOL_MEMORY",
    -1000072003: "VK_ERROR_INVALID_EXTERNAL_HANDLE",
    -1000161000: "VK_ERROR_FRAGMENTATION",
    -1000001004: "VK_ERROR_OUT_OF_DATE_KHR",
}

_vk: ModuleType | None = None


class VulkanError(MgpusimError):
    """A Vulkan call failed; the message names the call and the result."""

    def __init__(self, call: str, result: str):
        self.call = call
        self.result = result
        super().__init__(f"{call} failed: {result}")


def vk() -> ModuleType:
    """The `vulkan` module, imported once; a clear DependencyError when it cannot load."""
    global _vk
    if _vk is None:
        try:
            import vulkan as module  # noqa: PLC0415 - deliberate lazy import
        except ModuleNotFoundError as exc:
            raise DependencyError(f"the Python package 'vulkan' is missing ({exc.name}); "
                                  f"install it with: {PIP_VULKAN}") from None
        except OSError as exc:  # cffi could not dlopen libvulkan.so.1
            raise DependencyError(f"the Vulkan loader could not be loaded ({exc}); "
                                  f"install it with: {APT_RUNTIME}") from None
        _vk = module
    return _vk


def result_name(code: int | None) -> str:
    """A VkResult's name as `call` words it (the binding's exception class name)."""
    exc = vk().exception_codes.get(code)
    if exc is not None:
        return exc.__name__
    if code is not None and code in _EXTRA_CODES:
        return _EXTRA_CODES[code]
    return f"VkResult {code}"


def call(name: str, fn: Callable[..., Any], *args: Any) -> Any:
    """Run one binding call; turn any failure into a VulkanError naming `name`."""
    module = vk()
    try:
        return fn(*args)
    except KeyError as exc:  # an extension result code missing from the binding's table
        raise VulkanError(name, result_name(exc.args[0] if exc.args else None)) from None
    except module.VkTimeout:
        raise
    except module.VkNotReady:
        raise
    except module.VkException as exc:
        raise VulkanError(name, type(exc).__name__) from None
    except (module.VkError, module.ProcedureNotFoundError,
            module.ExtensionNotSupportedError) as exc:
        raise VulkanError(name, type(exc).__name__) from None


def require_compiler() -> list[str]:
    """The GLSL compiler command prefix (glslc, else glslangValidator)."""
    if shutil.which("glslc"):
        return ["glslc"]
    if shutil.which("glslangValidator"):
        return ["glslangValidator", "-V"]
    raise DependencyError(f"no GLSL compiler found (glslc or glslangValidator); install one with: "
                          f"{APT_COMPILER}")
