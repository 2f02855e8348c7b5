"""The host side of a lavapipe or NVIDIA run: host-to-host copies on threads (:mod:`.memcpy`),
the C heap kept from trimming (:mod:`.heap`) and the opt-in real-time policy (:mod:`.priority`).
Below the Vulkan wrapper: it tunes the process, it opens no device."""
