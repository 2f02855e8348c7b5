"""The real executor, in four layers: the Vulkan API wrapper (`vulkan/`: instances, devices,
queues, buffers, pipelines, copies, timestamps), the pass library on it (`passes/`, with the
shaders), host tuning beneath both (`host/`), and the runner that executes a schedule's
FrameProgram on them (`runner/`)."""
