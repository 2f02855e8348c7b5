"""Studies: named sets of configurations measured for real, a calibration and a validation.

:mod:`.spec` reads a study file; :mod:`.measure` measures it on Vulkan; :mod:`.pipeline` runs
the steps measure -> calibrate -> validate -> report. The lavapipe main job
(`experiments/lavapipe/study.toml`) and the NVIDIA validations (`experiments/h200/study.toml`,
`experiments/h100/study.toml`) are studies.
"""
from mgpusim.studies.spec import Entry, Study, load_study
from mgpusim.studies.steps import calibrate, load_runs, run, validate, write_report

__all__ = ["Entry", "Study", "calibrate", "load_runs", "load_study", "run", "validate", "write_report"]
