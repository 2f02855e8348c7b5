"""Does XR's frame make a mesh render dearer on lavapipe, with the runner's host threads out of
the picture? One lavapipe GPU, every command buffer recorded once; each frame is submitted
whole, then waited for, and frames of the kinds below alternate so that the machine's drift
falls on every kind alike.

- `sl`:  mesh A -> target A; present (copy A -> display)       (sort-last's 1-GPU frame)
- `xr`:  mesh L -> target L; empty; mesh R -> target R; empty; copy L, R -> final; empty;
         present (final -> display)                            (XR's frame, both views on GPU 0)
- `xr1`: as `xr`, but both views draw with one pass object (one vertex buffer, one target)
- `sl2`: mesh A; mesh A; present                               (two renders back to back)

    LP_NUM_THREADS=8 .venv/bin/python data/lavapipe/xr_frame_context_2026-11-26/seq_probe.py \
        OUT.csv FRAMES [WIDTH HEIGHT TRIANGLES]

A record of one experiment, not part of the package."""
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from mgpusim.real.vulkan.device import Gpu  # noqa: E402
from mgpusim.real.vulkan.framepasses import MeshShare, copy_image  # noqa: E402
from mgpusim.real.vulkan.instance import Instance  # noqa: E402
from mgpusim.real.vulkan.pipelines import RenderTarget  # noqa: E402

out, frames = sys.argv[1], int(sys.argv[2])
w, h, tri = (int(x) for x in (sys.argv[3:6] if len(sys.argv) > 5 else (192, 192, 10000)))
inst = Instance()
gpu = Gpu(inst, 0, "gpu0")
def mesh(eye):
    return MeshShare(gpu, [RenderTarget(gpu, w, h, depth=True)], (w, h), tri, 0, tri, eye=eye)
A, L, R = mesh(None), mesh(0), mesh(1)
final, display = gpu.image(2 * w, h), gpu.image(2 * w, h)
shown = gpu.image(w, h)
def empty(cmd):
    pass
def copy_into(src, x0):
    from mgpusim.real.vulkan.copies import copy_rect  # noqa: PLC0415
    return lambda cmd: copy_rect(cmd, src, final, (0, 0), (x0, 0), (w, h))
steps = {
    "sl": [("render0", A.record), ("e", lambda c: copy_image(c, A.targets[0].color, shown))],
    "xr": [("render0", L.record), ("e", empty), ("render1", R.record), ("e", empty),
           ("e", copy_into(L.targets[0].color, 0)), ("e", copy_into(R.targets[0].color, w)),
           ("e", empty), ("e", lambda c: copy_image(c, final, display))],
    "xr1": [("render0", L.record), ("e", empty), ("render1", L.record), ("e", empty),
            ("e", copy_into(L.targets[0].color, 0)), ("e", copy_into(L.targets[0].color, w)),
            ("e", empty), ("e", lambda c: copy_image(c, final, display))],
    "sl2": [("render0", A.record), ("render1", A.record),
            ("e", lambda c: copy_image(c, A.targets[0].color, shown))],
}
rows = []
for f in range(frames):
    for kind, seq in steps.items():
        subs = [(name, gpu.submit("graphics", rec, label=f"{kind}.{i}", key=(kind, i)))
                for i, (name, rec) in enumerate(seq)]
        for name, sub in subs:
            s, e = sub.timestamps_ns()
            if name != "e" and f >= 5:
                rows.append(dict(frame=f, kind=kind, task=name, us=(e - s) / 1e3))
d = pd.DataFrame(rows)
d.to_csv(out, index=False)
p = d.pivot_table(index="frame", columns=["kind", "task"], values="us")
print(p.median().round(1))
for col in p.columns:
    if col != ("sl", "render0"):
        r = p[col] / p[("sl", "render0")]
        print(col, "/ sl render: median %.3f quartiles %.3f %.3f" % tuple(r.quantile([.5, .25, .75])))
