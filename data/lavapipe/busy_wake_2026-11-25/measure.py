# The busy_wake share and wait measured on each committed job's calibration runs and, for
# comparison only, on its held-out runs (the calibration sees only the first):
#   .venv/bin/python data/lavapipe/busy_wake_2026-11-25/measure.py data/lavapipe/main_job_2026-11-25_8threads ...
import sys
import tomllib
from pathlib import Path

from mgpusim.calibration.busy_wake_fit import fit_busy_wake
from mgpusim.model.profile import BUSY_WAKE_WINDOW_NS
from mgpusim.studies.steps import load_runs
from mgpusim.studies.spec import load_study

study = load_study("experiments/lavapipe/study.toml")
for job in sys.argv[1:]:
    profile = Path(job) / "profile.toml"
    data = tomllib.loads(profile.read_text())
    for name, entries in (("calibration", study.calibration), ("held-out", study.held_out)):
        runs = load_runs(study, entries, Path(job) / "runs", profile)
        print(Path(job).name, name, fit_busy_wake(runs, data, BUSY_WAKE_WINDOW_NS), flush=True)
