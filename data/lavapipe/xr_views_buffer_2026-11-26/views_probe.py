"""Do XR's views on one GPU render slower because each uploads its own copy of the mesh?

Runs `experiments/lavapipe/xr.toml` with four views on one lavapipe GPU (the study's
`xr_sim_4views`, 8 rasterizer threads), alternating two variants run by run so that the machine's drift falls on
both alike: `own` (each view's MeshShare uploads its own vertex buffer, the runner as it is) and
`shared` (the views of a GPU draw one buffer: MeshShare patched from outside). Writes every
run's render durations per view to OUT/views.csv and prints the medians.

    .venv/bin/python data/lavapipe/xr_views_buffer_2026-11-26/views_probe.py OUT [PAIRS]

A record of one experiment, not part of the package.
"""
from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

import mgpusim.real.vulkan.framepasses as fp
from mgpusim.cli import main

_INIT = fp.MeshShare.__init__
_SHARED: dict = {}
MODE = {"shared": False}


def _init(self, gpu, targets, frame, triangles, first, count, **kw):
    _INIT(self, gpu, targets, frame, triangles, first, count, **kw)
    if not MODE["shared"] or self.vertices is None:
        return
    key = (id(gpu), triangles, first, count)
    if key in _SHARED:  # draw the first view's buffer; free this one's now
        self._owned.remove(self.vertices)
        self.vertices.destroy()
        self.vertices = _SHARED[key]
    else:
        _SHARED[key] = self.vertices


def run(out: Path, shared: bool) -> pd.DataFrame:
    MODE["shared"] = shared
    _SHARED.clear()
    sets = ["schedule.gpus=1", "schedule.mode=simulated", "schedule.views=4", "schedule.frames=40"]
    rc = main(["run", "experiments/lavapipe/xr.toml", *[a for s in sets for a in ("--set", s)],
               "--lp-threads", "8", "--out", str(out)])
    assert rc == 0, rc
    t = pd.read_csv(out / "trace.csv")
    r = t[(t.step == "render") & (t.frame >= 0)]
    return pd.DataFrame({"task": r.task, "frame": r.frame,
                         "ms": (r.end_ns - r.start_ns) / 1e6})


if __name__ == "__main__":
    fp.MeshShare.__init__ = _init
    root, pairs = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 6
    rows = []
    for i in range(pairs):
        for shared in ((False, True) if i % 2 == 0 else (True, False)):
            df = run(root / f"{i}_{'shared' if shared else 'own'}", shared)
            rows.append(df.assign(pair=i, variant="shared" if shared else "own"))
    all_rows = pd.concat(rows, ignore_index=True)
    all_rows.to_csv(root / "views.csv", index=False)
    per_run = all_rows.groupby(["pair", "variant", "task"])["ms"].median().unstack("task")
    print(per_run.round(3).to_string())
    print(all_rows.groupby(["variant", "task"])["ms"].median().unstack("task").round(3).to_string())
