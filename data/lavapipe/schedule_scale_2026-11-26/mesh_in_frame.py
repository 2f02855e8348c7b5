"""Each 1-GPU run's mesh passes against the job's microbenchmark fit: the median of measured
duration over the fit's cost, per schedule and task (with the task before it on its queue).

    python mesh_in_frame.py data/lavapipe/main_job_2026-11-25_8threads ...

Reads each job's runs/ (steady windows) and profile_microbenchmarks.toml; run from the project
root with the package importable."""
from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from mgpusim.calibration.run_fit import tasks_by_name
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import load_profile
from mgpusim.studies.steps import load_runs
from mgpusim.studies.spec import load_study
from mgpusim.model.tasks import PassTask

STUDY = Path("experiments/lavapipe/study.toml")


def rows(job: Path) -> pd.DataFrame:
    study = load_study(STUDY)
    costs = CostModel(load_profile(job / "profile_microbenchmarks.toml"))
    out = []
    for half, entries in (("calibration", study.calibration), ("held-out", study.held_out)):
        for exp, trace in load_runs(study, entries, job / "runs"):
            if exp.schedule.gpus != 1:
                continue
            tasks = tasks_by_name(exp)
            steady = trace[(trace["frame"] >= exp.schedule.warmup_frames) & (trace["device"] != "host")]
            steady = steady.sort_values("start_ns")
            before = steady["task"].shift(1)
            for (_, r), prev in zip(steady.iterrows(), before):
                task = tasks.get(r["task"])
                if not isinstance(task, PassTask) or task.kind != "mesh":
                    continue
                fit = costs.pass_cost_ns(task.queue.device, "mesh", task.work)
                out.append(dict(job=job.name, set=half, schedule=exp.schedule.name, task=r["task"],
                                after=str(prev), ratio=(r["end_ns"] - r["start_ns"]) / fit))
    return pd.DataFrame(out)


if __name__ == "__main__":
    df = pd.concat([rows(Path(j)) for j in sys.argv[1:]])
    table = df.groupby(["job", "set", "schedule", "task", "after"]).ratio.agg(["median", "count"])
    print(table.round(3).to_string())
