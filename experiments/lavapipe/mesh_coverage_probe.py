"""Probe of the mesh cost on lavapipe: one pass over sizes (128x96-640x480), triangle counts
(5k-60k), sort-last halves, each eye, half-eye columns and sort-first strips, the fastest of
its repetitions over interleaved rounds. Writes one JSON line per placement.

    python experiments/lavapipe/mesh_coverage_probe.py OUT.jsonl [ROUNDS]
    python experiments/lavapipe/mesh_coverage_fit.py OUT.jsonl [MORE.jsonl ...]

Run it on a quiet machine (about 15 s a round). docs/model.md ("Mesh cost") has the result."""
import itertools, json, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from mgpusim.real.vulkan.hostheap import keep_heap
from mgpusim.real.vulkan.host_machine import make_gpus, close_gpus
from mgpusim.real.vulkan.passes import Mesh
from mgpusim.model.geometry import even_split

keep_heap()
out = open(sys.argv[1], "w")
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
gpu = make_gpus(1)[0]
variants = []
for (w, h), T in itertools.product([(128, 96), (256, 192), (448, 336), (640, 480)], [5000, 20000, 60000]):
    variants.append(dict(w=w, h=h, T=T, first=0, count=T, eye=None, rect=None))
    for k in range(2):  # sort-last halves
        first = T * k // 2
        variants.append(dict(w=w, h=h, T=T, first=first, count=T * (k + 1) // 2 - first, eye=None, rect=None))
    cols = even_split(w, 2)
    for eye in (0, 1):  # XR: whole eye and half-eye columns
        variants.append(dict(w=w, h=h, T=T, first=0, count=T, eye=eye, rect=None))
        x0 = 0
        for c in cols:
            variants.append(dict(w=w, h=h, T=T, first=0, count=T, eye=eye, rect=(x0, 0, c, h)))
            x0 += c
    rows = even_split(h, 2)  # sort-first strips
    variants.append(dict(w=w, h=h, T=T, first=0, count=T, eye=None, rect=(0, 0, w, rows[0])))
    variants.append(dict(w=w, h=h, T=T, first=0, count=T, eye=None, rect=(0, rows[0], w, rows[1])))
print(len(variants), "variants", flush=True)
passes = [Mesh(gpu, v["w"], v["h"], v["T"], first=v["first"], count=v["count"], eye=v["eye"], rect=v["rect"]) for v in variants]
keys = [("probe", i) for i in range(len(passes))]
best = [float("inf")] * len(passes)
t0 = time.time()
for r in range(rounds):
    for i, (p, k) in enumerate(zip(passes, keys)):
        for rep in range(3 if r else 5):
            d = gpu.submit(p.queue, p.record, label="mesh", key=k).wait().duration_ns
            if r or rep >= 2:
                best[i] = min(best[i], d)
    print("round", r, time.time() - t0, flush=True)
for v, b in zip(variants, best):
    out.write(json.dumps({**v, "ns": b}) + "\n")
for p in passes:
    p.destroy()
close_gpus([gpu])
