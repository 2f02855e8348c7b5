"""The speed probe's two passes repeated REPS times on one lavapipe GPU of THREADS rasterizer
threads: quantiles and medians of blocks of 40, to see how a machine's speed moves within a minute.

    python3 probe_series.py THREADS REPS   (pinned with taskset to the CPUs to try)
"""
import sys, numpy as np
from mgpusim.real.vulkan.host_machine import make_gpus, close_gpus
from mgpusim.real.vulkan import microbench as m
threads = int(sys.argv[1]); reps = int(sys.argv[2])
gpus = make_gpus(1, lp_threads=[threads])
for name, p in [("mesh", dict(width=[256], height=[192], triangles=[10000])), ("fragment_loop", dict(width=[256], height=[192], iterations=[500]))]:
    d = m.measure(name, gpus, p, reps=reps, warmup=12).duration_ns.to_numpy() / 1e6
    blocks = np.median(d[: len(d)//40*40].reshape(-1, 40), axis=1)
    print(name, threads, "q01/10/50/90/99", np.quantile(d, [.01,.1,.5,.9,.99]).round(3), "block medians", blocks.round(2), flush=True)
close_gpus(gpus)
