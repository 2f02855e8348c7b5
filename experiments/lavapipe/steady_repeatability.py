"""How much a configuration's measured frame time moves between two main jobs, by estimator.

    python experiments/lavapipe/steady_repeatability.py OUT_A OUT_B

OUT_A and OUT_B are `mgpusim main` output folders (their runs/ are read, nothing is run).
For every configuration in both, it prints the median and worst |A / B - 1| of the frame time
estimated as the fastest whole run and as the steady window (mgpusim.validation.steady_window).
"""
from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from mgpusim.validation import steady_window as sw
from mgpusim.results.summary import frames_from_trace, summarize

def warmup_frames(run: Path) -> int:
    """The schedule's warm-up of the experiment the run was made from."""
    experiment = json.loads((run / "summary.json").read_text())["config"]["file"]
    return int(tomllib.loads(Path(experiment).read_text())["schedule"].get("warmup_frames", 2))


def estimates(config_dir: Path) -> dict[str, float]:
    runs = [run for run in sorted(config_dir.glob("run*")) if run.is_dir()]
    warmup = warmup_frames(runs[0])
    frames = [frames_from_trace(pd.read_csv(run / "trace.csv", keep_default_na=False)) for run in runs]
    whole = [summarize(f, None, warmup)["frame_time_ms"] for f in frames]
    wins = [w for i, f in enumerate(frames) for w in sw.windows(f, warmup, i)]
    return {"fastest whole run": min(whole), "steady window": sw.pick(wins).frame_time_ms}


def main(a: Path, b: Path) -> None:
    names = sorted({p.name for p in (a / "runs").iterdir()} & {p.name for p in (b / "runs").iterdir()})
    diffs: dict[str, list[float]] = {}
    for name in names:
        ea, eb = estimates(a / "runs" / name), estimates(b / "runs" / name)
        for k in ea:
            diffs.setdefault(k, []).append(abs(ea[k] / eb[k] - 1))
    for k, d in diffs.items():
        print(f"{k:18}: job-to-job |difference| median {np.median(d):.1%}, worst {max(d):.1%} "
              f"over {len(d)} configurations")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]))
