"""mgpusim's real Vulkan backend (lavapipe by default, NVIDIA where present); see docs/vulkan.md.

The runner's entry points (importing this package does not load the Vulkan binding yet):
    make_gpus(n, lp_threads=..., physical=...) -> list[Gpu]      (machine.py)
    Gpu.queue(kind) / Gpu.has_dedicated(kind) / Gpu.semaphore()   (device.py)
    Gpu.submit(queue, record, wait=[...], signal=[...]) -> Submission
    Submission.wait() / .done() / .timestamps_ns() / .duration_ns
    framepasses.* (the passes the runner executes), passes.* (the same passes on images of
    their own, for measuring: FragmentLoop / Mesh / CompositeSortFirst / CompositeSortLast /
    Present / ParticleRender),
    particles.ParticleUpdate, copies.copy_* recorders, hostcopy.HostCopier
"""
