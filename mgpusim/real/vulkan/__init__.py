"""mgpusim's Vulkan API wrapper (lavapipe by default, NVIDIA where present); see docs/vulkan.md.

What the runner and the microbenchmarks use (importing this package does not load the Vulkan
binding yet):
    make_gpus(n, lp_threads=..., physical=...) -> list[Gpu]      (machine.py)
    Gpu.queue(kind) / Gpu.has_dedicated(kind) / Gpu.semaphore()   (device.py)
    Gpu.submit(queue, record, wait=[...], signal=[...]) -> Submission
    Submission.wait() / .done() / .timestamps_ns() / .duration_ns
    copies.copy_* recorders, pipelines.* (targets, pipelines, descriptor sets)
The passes themselves are in :mod:`mgpusim.real.passes`, host copies in :mod:`mgpusim.real.host`.
"""
