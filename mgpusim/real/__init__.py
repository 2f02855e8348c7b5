"""The real executor: the Vulkan backend (`vulkan/`) and the runner that executes a schedule's
FrameProgram on it (`runner/`)."""
