# With busy_wake.patch applied: the busy_wake share and wait measured on each job's calibration and
# held-out runs (python busy_wake_measure.py data/lavapipe/main_job_2026-11-25_8threads ...).
import sys, tomllib
from pathlib import Path
from mgpusim.calibration.run_fit import fit_busy_wake
from mgpusim.studies.spec import load_study
from mgpusim.studies.steps import load_runs
study = load_study("experiments/lavapipe/study.toml")
for job in sys.argv[1:]:
    prof = Path(job)/"profile.toml"
    data = tomllib.loads(prof.read_text())
    for name, entries in (("calibration", study.calibration), ("held-out", study.held_out)):
        runs = load_runs(study, entries, Path(job)/"runs", prof)
        print(job.split("/")[-1], name, fit_busy_wake(runs, data))
