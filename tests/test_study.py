"""Study files: the shipped ones load, and bad ones fail with one error naming file and field."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from mgpusim.model.errors import InputError
from mgpusim.studies import load_study
from mgpusim.vmgpu.frame_times import is_frame_time_study
from mgpusim.vmgpu.frame_times import load_study as load_frame_time_study

ROOT = Path(__file__).resolve().parents[1]
ALL_STUDIES = sorted((ROOT / "experiments").glob("*/study.toml"))
#: Studies of an external renderer's frame times (their own loader, mgpusim/vmgpu/frame_times.py)
FRAME_TIME_STUDIES = [p for p in ALL_STUDIES if is_frame_time_study(p)]
STUDIES = [p for p in ALL_STUDIES if p not in FRAME_TIME_STUDIES]


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: p.parent.name)
def test_shipped_studies_load_and_their_entries_build(path: Path) -> None:
    study = load_study(path)
    for entry in study.entries():
        exp = entry.load(study.profile)
        assert exp.schedule.gpus >= 1


@pytest.mark.parametrize("path", FRAME_TIME_STUDIES, ids=lambda p: p.parent.name)
def test_frame_time_studies_load_and_the_runner_s_steps_refuse_them(path: Path) -> None:
    study = load_frame_time_study(path)
    assert study.fits and (study.runs / "runs.parquet").is_file()
    with pytest.raises(InputError, match="study validate") as err:
        load_study(path)
    assert err.value.field == "kind"


def test_the_vmgpu_study_is_a_frame_time_study() -> None:
    assert [p.parent.name for p in FRAME_TIME_STUDIES] == ["vmgpu"]


def test_lavapipe_study_keeps_held_out_apart() -> None:
    study = load_study(ROOT / "experiments" / "lavapipe" / "study.toml")
    assert len(study.held_out) >= 8 and study.runs.steady_window
    assert not {e.name for e in study.calibration} & {e.name for e in study.held_out}


@pytest.mark.parametrize("edit, field", [
    (("[runs]", "[runs]\nrepeets = 3"), "runs.repeets"),
    (('base = "machine"', 'base = "gpu"'), "calibration.base"),
    (('run_fit_alone = ["composite_sort_last"]', 'run_fit_alone = ["composite"]'),
     "calibration.run_fit_alone"),
    (('experiment = "sort_first.toml"', 'experiment = "nope.toml"'), "experiment"),
    (('name = "sf_1gpu_128x96_it500"', 'name = "sf_1gpu_256x192_it2000"'), None),
])
def test_bad_study_is_one_error_naming_the_field(tmp_path: Path, edit: tuple[str, str], field: str | None) -> None:
    src = ROOT / "experiments" / "lavapipe" / "study.toml"
    bad = src.parent / f"bad_study_{os.getpid()}_tmp.toml"  # one per test process (xdist)
    bad.write_text(src.read_text().replace(*edit, 1))
    try:
        with pytest.raises(InputError) as err:
            load_study(bad)
    finally:
        bad.unlink()
    assert str(bad) in str(err.value)
    if field:
        assert field in str(err.value)


def test_lavapipe_threads_follow_the_cores_this_process_may_use(monkeypatch: pytest.MonkeyPatch) -> None:
    study = load_study(ROOT / "experiments" / "lavapipe" / "study.toml")
    assert study.lavapipe_threads_per_core == 4
    monkeypatch.setattr("os.sched_getaffinity", lambda _pid: {0, 1, 2})
    assert study.lavapipe_threads() == 12
    from dataclasses import replace
    assert replace(study, lavapipe_threads_per_core=None).lavapipe_threads() is None


def test_bad_lavapipe_threads_per_core_names_the_field(tmp_path: Path) -> None:
    src = ROOT / "experiments" / "lavapipe" / "study.toml"
    bad = src.parent / f"bad_study_threads_{os.getpid()}_tmp.toml"
    bad.write_text(src.read_text().replace("lavapipe_threads_per_core = 4", "lavapipe_threads_per_core = 0", 1))
    try:
        with pytest.raises(InputError, match="lavapipe_threads_per_core"):
            load_study(bad)
    finally:
        bad.unlink()
