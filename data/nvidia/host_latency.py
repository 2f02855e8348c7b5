"""How long after a GPU finishes does a waiting Python thread notice (fence wake-up + GIL)?

Submits a tiny task, waits on its fence from the main thread, and records host time when the
wait returns minus the task's end timestamp (host clock via calibrated timestamps). Three
conditions: idle interpreter; 4 busy Python threads (as the runner's submit threads recording
command buffers); the same with sys.setswitchinterval(0.0002). Writes a CSV.
Usage (device machine): python3 data/nvidia/host_latency.py OUT.csv
"""
import sys
import threading
import time

import pandas as pd

from mgpusim.real.vulkan.host_machine import close_gpus, make_gpus

out = sys.argv[1]
gpus = make_gpus(1)
g = gpus[0]
rows = []


def busy(stop):
    x = 0
    while not stop.is_set():
        for i in range(1000):
            x += i * i


for cond, nbusy, interval in (("idle", 0, None), ("busy4", 4, None), ("busy4_si200us", 4, 0.0002)):
    old = sys.getswitchinterval()
    if interval:
        sys.setswitchinterval(interval)
    stop = threading.Event()
    ts = [threading.Thread(target=busy, args=(stop,)) for _ in range(nbusy)]
    for t in ts:
        t.start()
    for rep in range(60):
        sub = g.submit("graphics", lambda cmd: None, label="probe")
        sub.wait()
        now = time.monotonic_ns()
        start, end = sub.timestamps_ns()
        rows.append({"condition": cond, "repetition": rep, "latency_ns": now - end})
        time.sleep(0.002)
    stop.set()
    for t in ts:
        t.join()
    sys.setswitchinterval(old)
close_gpus(gpus)
df = pd.DataFrame(rows)
df.to_csv(out, index=False)
print(df.groupby("condition").latency_ns.describe())
