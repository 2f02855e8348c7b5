"""Runner A/B: the same 192x192 mesh of 10k triangles as sort-last's 1-GPU render (mono camera)
and as XR's two eye views on one GPU (`mode=simulated`), alternated run by run (80 frames,
8 rasterizer threads), so that the drifting machine's speed falls on both alike.

    .venv/bin/python data/lavapipe/xr_view_cost_2026-11-26/ab_probe.py OUT PAIRS [strong]

A record of one experiment, not part of the package."""
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from mgpusim.cli import main
root = Path(sys.argv[1]); pairs = int(sys.argv[2])
cases = {
  "sl": ["experiments/lavapipe/sort_last.toml", "schedule.gpus=1", "scene.width=192", "scene.height=192", "scene.passes.0.triangles=10000"],
  "xr2": ["experiments/lavapipe/xr.toml", "schedule.gpus=1", "schedule.mode=simulated", "schedule.views=2"],
}
if len(sys.argv) > 3 and sys.argv[3] == "strong":  # also XR's views rendered under strong scaling
    cases["xr2s"] = cases["xr2"] + ["schedule.scaling=strong"]
rows = []
for i in range(pairs):
    for name in (list(cases) if i % 2 == 0 else list(cases)[::-1]):
        exp, *sets = cases[name]
        out = root / f"{name}_{i}"
        args = ["run", exp, "--lp-threads", "8", "--out", str(out), "--set", "schedule.frames=80"]
        for s in sets: args += ["--set", s]
        assert main(args) == 0
        t = pd.read_csv(out / "trace.csv"); t = t[(t.frame >= 12) & (t.step == "render")]
        for task, g in t.groupby("task"):
            rows.append(dict(pair=i, case=name, task=task, us=float((g.end_ns - g.start_ns).median() / 1e3)))
df = pd.DataFrame(rows); df.to_csv(root / "ab.csv", index=False)
print(df.groupby(["case", "task"]).us.median().round(0))
p = df.groupby(["pair", "case"]).us.median().unstack()
for c in [c for c in cases if c != "sl"]:
    print(f"{c} eye view / sl mono render, per pair: median %.3f IQR %.3f-%.3f"
          % tuple((p[c] / p.sl).quantile([.5, .25, .75])))
