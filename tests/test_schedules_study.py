"""The lavapipe study (`mgpusim main`) covers every schedule and is ready to run: every entry
builds a program the Vulkan runner accepts, each schedule has calibration and >= 6 held-out
configurations, and the held-out sizes reach 3x the calibrated pixels."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from mgpusim.schedules.program import build_program
from mgpusim.studies.study_file import load_study

STUDY = Path(__file__).resolve().parents[1] / "experiments" / "lavapipe" / "study.toml"


def test_every_entry_builds_a_program_the_runner_accepts():
    study = load_study(STUDY)
    cal, held = defaultdict(list), defaultdict(list)
    for half, entries in ((cal, study.calibration), (held, study.held_out)):
        for e in entries:
            exp = e.load(study.profile)
            program = build_program(exp)
            assert program.resources is not None, e.name
            refused = [t.name for tasks in program.templates for t in tasks
                       if "unsupported" in getattr(t, "params", {})]
            assert not refused, (e.name, refused)
            half[program.schedule].append(exp.scene.pixels)
    for schedule in ("sort_first", "sort_last", "afr", "pipelining", "xr", "particles"):
        assert cal[schedule] and len(held[schedule]) >= 6, schedule
        assert max(held[schedule]) >= 3 * max(cal[schedule]) * 0.95, schedule
