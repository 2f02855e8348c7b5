"""Bad input stops with one clear message naming the file and the field; no traceback, no hang."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mgpusim import InputError, ScheduleError, load_experiment, simulate
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import Dep, PassTask, QueueRef
from mgpusim.schedules.base import FrameProgram
from mgpusim.schedules.experiment import parse_experiment
from mgpusim.sim.engine import Engine
from tests.conftest import experiment_dict, profile_dict

ROOT = Path(__file__).resolve().parents[1]


def profile_error(mutate) -> InputError:
    data = profile_dict()
    mutate(data)
    with pytest.raises(InputError) as info:
        parse_profile(data, "p.toml")
    return info.value


@pytest.mark.parametrize("mutate, field, words", [
    (lambda d: d["host"].pop("memory_bandwidth_gbps"), "host.memory_bandwidth_gbps", "missing"),
    (lambda d: d["host"].update(memory_bandwidth_gbps=-3.0), "host.memory_bandwidth_gbps", "> 0"),
    (lambda d: d["host"].update(memcpy_threads="four"), "host.memcpy_threads", "integer"),
    (lambda d: d["gpus"][0]["link"].update(h2d_gbps=0), "gpus[0].link.h2d_gbps", "> 0"),
    (lambda d: d["gpus"][0]["link"].update(pcie_gen=9), "gpus[0].link.pcie_gen", "one of"),
    (lambda d: d["gpus"][0].update(memory_gb=8), "gpus[0].memory_gb", "unknown key"),
    (lambda d: d["gpus"][0]["costs"]["mesh"].update(ms_per_triangle=1), "gpus[0].costs.mesh.ms_per_triangle", "ns_per"),
    (lambda d: d["gpus"][0]["queues"].update(graphics=0), "gpus[0].queues.graphics", "at least one"),
])
def test_bad_profile_names_file_and_field(mutate, field, words):
    err = profile_error(mutate)
    assert err.file == "p.toml" and err.field == field
    assert words in str(err)


def experiment_error(mutate, profile=None) -> InputError:
    data = experiment_dict()
    mutate(data)
    prof = parse_profile(profile or profile_dict(), "p.toml")
    with pytest.raises(InputError) as info:
        parse_experiment(data, "e.toml", profile=prof)
    return info.value


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["schedule"].update(gpus=3), "schedule.gpus"),
    (lambda d: d["schedule"].update(name="sort_middle"), "schedule.name"),
    (lambda d: d["schedule"].update(gpu=2), "schedule.gpu"),
    (lambda d: d["scene"].update(width="wide"), "scene.width"),
    (lambda d: d["scene"].pop("height"), "scene.height"),
    (lambda d: d["scene"]["passes"][0].update(kind="raytrace"), "scene.passes[0].kind"),
    (lambda d: d["scene"]["passes"][0].update(iterations=-1), "scene.passes[0].iterations"),
    (lambda d: d["schedule"].update(warmup_frames=50), "schedule.warmup_frames"),
])
def test_bad_experiment_names_file_and_field(mutate, field):
    err = experiment_error(mutate)
    assert err.file == "e.toml" and err.field == field


def test_missing_cost_coefficient_is_reported_before_running():
    prof = profile_dict()
    del prof["gpus"][0]["costs"]["mesh"]["ns_per_triangle"]
    exp = parse_experiment(experiment_dict(schedule="sort_last"), "e.toml", profile=parse_profile(prof, "p.toml"))
    with pytest.raises(InputError, match=r"gpus\[0\].costs.mesh.ns_per_triangle"):
        simulate(exp)


def test_unsatisfiable_dependency_is_reported_not_hung():
    """Task b waits for a that is queued behind b on the same in-order queue: a deadlock."""
    q = QueueRef(0, "graphics")
    tasks = (PassTask("b", "render", q, "present", {}, (Dep("a"),)),
             PassTask("a", "render", q, "present", {}),
             PassTask("present", "present", q, "present", {}, (Dep("a"),)))
    program = FrameProgram("broken", 1, 3, 0, (tasks,))
    prof = parse_profile(profile_dict(), "p.toml")
    with pytest.raises(ScheduleError, match="frame 0 b"):
        Engine(program, CostModel(prof)).run()


def test_cli_prints_one_line_without_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    text = (ROOT / "experiments" / "sort_first_tc1.toml").read_text().replace(
        'profile = "../hardware_profiles/tc1.toml"', f'profile = "{ROOT}/hardware_profiles/tc1.toml"')
    bad.write_text(text.replace("width = 1024", "width = -1024"))
    proc = subprocess.run([sys.executable, "-m", "mgpusim.cli", "simulate", str(bad), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "scene.width" in lines[0] and str(bad) in lines[0]
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_set_overrides_are_validated_like_file_values():
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml",
                          {"schedule.gpus": 3, "scene.width": 640, "scene.height": 480, "schedule.frames": 20})
    assert (exp.schedule.gpus, exp.scene.width, exp.scene.height, exp.schedule.frames) == (3, 640, 480, 20)
    with pytest.raises(InputError, match="schedule.gpus"):
        load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.gpus": 4})


def test_toml_syntax_error_names_the_file(tmp_path):
    bad = tmp_path / "x.toml"
    bad.write_text("name = \n")
    with pytest.raises(InputError, match="x.toml: not valid TOML"):
        load_experiment(bad)


def test_set_indexes_arrays_of_tables():
    exp = load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"scene.passes.0.iterations": 123})
    assert exp.scene.passes[0].params["iterations"] == 123
    with pytest.raises(InputError, match="'3' is not an index below 1"):
        load_experiment(ROOT / "experiments" / "sort_first_tc1.toml", {"scene.passes.3.iterations": 1})
