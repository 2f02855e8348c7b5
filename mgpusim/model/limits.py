"""Upper bounds on inputs, so that simulated time fits in int64 nanoseconds and a run's
allocations stay in memory.

Each bound is far above any machine or frame the tool is meant for, and each is named in the
message that refuses a value above it (with the reason, `WHY_*`). docs/formats.md lists them.
"""
from __future__ import annotations

#: Simulated time is int64 ns: 2^63 - 1 ns is about 292 years.
INT64_MAX = 2 ** 63 - 1

#: One task (a pass, a copy, a host copy: its bytes at the slower of a memcpy thread and host
#: memory) and every fixed time in a profile (latency, fixed cost, dispatch, submit, gap) may
#: last at most this: 10^12 ns = 1000 s. A run of MAX_FRAMES frames passes int64 only where
#: its frames take nearly a whole such task each, one after another (the run is then refused,
#: naming the int64 limit). A task an override pushes past it is refused naming that override.
MAX_TASK_NS = 10 ** 12
WHY_TIME = "keeps simulated time within int64 ns"

#: Frames of one run, as read (`schedule.frames`, `mgpusim case --frames`). Why 10^7: a run
#: past MAX_RECORDED_FRAMES goes on only once it has fast-forwarded (below), and a
#: fast-forwarded run holds two arrays per frame and writes a table row per frame, task and
#: link transfer; at 10^7 frames every shipped experiment that fast-forwards runs with its
#: default outputs in under 1 GiB (`benchmarks/largest_run_memory.py --all`: `sort_last_tc1`
#: the largest, 947-966 MiB); that memory grows with the frames (10^8: about ten times it).
MAX_FRAMES = 10_000_000
WHY_FRAMES = "a fast-forwarded run holds two arrays and writes rows per frame; 10^7 fit in 1 GiB"

#: Frames a run may simulate without having fast-forwarded (its state repeating: the exact
#: fast-forward, :mod:`mgpusim.sim.fastforward`, or the analytic level's repeat; not the
#: analytic level's affine stretch, which fills in a run whose state never repeats and holds
#: every frame's rows). Why 10^6: a run whose state does not repeat simulates every frame and
#: keeps every frame's records (its trace rows, link intervals and skipped frames: what its
#: tables are built from), so its memory grows with each frame; vmgpu
#: (`experiments/vmgpu/vmgpu.toml`, which does not repeat at that length) reached 1.4 GiB at
#: 1.15 x 10^6 frames, and 10^6 frames one by one take a minute or more. A longer run that has
#: not fast-forwarded by the time that is known (the fast-forward gave up, or is off) is
#: refused then, before it runs on and before anything is written.
MAX_RECORDED_FRAMES = 1_000_000
WHY_RECORDED = "1.4 GiB at 1.15 x 10^6 frames of a run that does not repeat"

#: GPUs of a profile or a schedule, queues of one family, memcpy threads, CPU cores: the
#: engine builds one process per queue and thread, schedules build tasks per GPU pair.
MAX_GPUS = 64
MAX_QUEUES = 64
MAX_THREADS = 1024
WHY_ALLOC = "bounds the tasks, queues and threads the model allocates"

#: Buffers and frames in flight (multi-buffering depth), and copy chunks per buffer: each adds
#: tasks or dependencies to every frame.
MAX_BUFFERS = 64
MAX_CHUNKS = 1024

#: Image side in pixels (Vulkan's largest maxImageDimension2D is 32768 on current GPUs; twice
#: that leaves room for what-ifs) and bytes per pixel (RGBA32F x 4 samples = 64).
MAX_SIDE = 65536
MAX_BYTES_PER_PIXEL = 64
WHY_IMAGE = "larger than any GPU's image; keeps byte counts exact"

#: Byte counts (memory sizes, data sets, copies): 2^50 = 1 PiB.
MAX_BYTES = 2 ** 50
WHY_BYTES = "1 PiB, more than any machine's memory"

#: Work amounts of a pass (iterations, triangles, particles, inputs, output bytes...): 10^15.
#: Durations themselves are bounded by MAX_TASK_NS when the cost model computes them.
MAX_WORK = 1e15
WHY_WORK = "10^15; the pass's time is checked against 10^12 ns too"

#: Bandwidths in GB/s (bytes per ns): 10^12 GB/s, high enough to stand for a free copy in a
#: what-if, low enough that byte counts over it stay exact fractions of reasonable size.
MAX_GBPS = 1e12
WHY_GBPS = "10^12 GB/s, as good as free"

#: Cost coefficients (ns per unit of work) and speed factors.
MAX_COEFFICIENT = 1e12
MAX_SPEED = 1e6

#: An input file (experiment, profile, study, case, measure table, JSON record) is read whole:
#: the largest shipped one is under 1 MiB; this refuses /dev/zero or a disk image given by mistake.
MAX_INPUT_FILE_BYTES = 64 << 20

#: A name that becomes one file or folder name (a configuration's, an experiment's): the
#: longest name common file systems take, in bytes of UTF-8.
MAX_NAME_BYTES = 255

#: Points of one sweep (the product of its grid), checked before the grid is enumerated: at
#: the fastest (~30 ms a point) 10^5 points take about an hour on one core, and each leaves a
#: file in the sweep's folder; a larger study is several sweeps.
MAX_SWEEP_POINTS = 100_000
WHY_SWEEP = "one file and one simulation each; split a larger grid into several sweeps"

#: Local processes of one sweep: each imports the model (~100 MB).
MAX_SWEEP_WORKERS = 256
