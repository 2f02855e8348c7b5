"""Write the frame-capture examples of examples/frames/ from committed measured runs.

    python scripts/frame_examples.py        (from the checkout's root)

- pipelining_lavapipe.perfetto.json: mgpusim's own Perfetto export (Chrome trace-event JSON)
  of four steady frames of the lavapipe main job's one-GPU pipelining run;
- pipelining_lavapipe.csv: the same run's steady frames as the CSV format (pass, queue, gpu_ms,
  reads, writes, bytes, frame, pixel_share: 1 for the runner's fragment loops and filters, 0 for
  meshes), what each pass reads and writes taken from the recorded scene;
- xr_two_views_lavapipe.csv: the XR run with both views on one GPU, a row per view (`view`);
- pipelining_lavapipe.toml: the CSV example imported (`mgpusim frame import`) with the
  lavapipe profile, as the notebook and docs/formats.md use it.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.frames.formats import read_run  # noqa: E402
from mgpusim.io.perfetto import chrome_trace_json  # noqa: E402

RUNS = ROOT / "data/lavapipe/history/main_job_2026-11-25/runs"
OUT = ROOT / "examples/frames"


def _csv(run: str, frames: int, path: Path) -> None:
    slices, _ = read_run(RUNS / run)
    first = sorted(slices["frame"].unique())[:frames]
    rows = slices[slices["frame"].isin(first)]
    table = pd.DataFrame({"frame": rows["frame"], "pass": rows["name"], "queue": rows["queue"],
                          "gpu_ms": rows["ms"].round(4), "reads": rows["reads"].map(";".join),
                          "writes": rows["writes"].map(";".join),
                          "bytes": rows["bytes"].map(lambda b: ";".join(map(str, b))),
                          "pixel_share": rows["pixel_share"]})
    if (rows["view"] >= 0).any():
        table.insert(2, "view", rows["view"])
    table.to_csv(path, index=False)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    trace = pd.read_parquet(RUNS / "runs.parquet")
    pipe = trace[trace["run"] == "pipe_1gpu/steady"].drop(columns="run")
    pipe = pipe[pipe["frame"] < pipe["frame"].min() + 4]
    (OUT / "pipelining_lavapipe.perfetto.json").write_text(
        chrome_trace_json(pipe, None, "lavapipe pipelining run, one GPU (pipe_1gpu)"))
    _csv("pipe_1gpu/steady", 8, OUT / "pipelining_lavapipe.csv")
    _csv("xr_sim_2views/steady", 8, OUT / "xr_two_views_lavapipe.csv")
    subprocess.run([sys.executable, "-m", "mgpusim", "frame", "import",
                    "examples/frames/pipelining_lavapipe.csv", "--size", "256x192",
                    "--profile", "hardware_profiles/lavapipe_2core.toml",
                    "--out", "examples/frames/pipelining_lavapipe.toml"], cwd=ROOT, check=True,
                   env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


if __name__ == "__main__":
    main()
