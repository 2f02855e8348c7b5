"""Speed-normalized prediction: the profile at another host speed (pure), each run's speed from
its probes, the speed flag, and the columns the report and summary.json get from them (on a
committed lavapipe job's runs, no device)."""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_profile
from mgpusim.commands.main_job import LAVAPIPE_STUDY
from mgpusim.measure import run_speed
from mgpusim.measure import speed_norm as sn
from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.speed_scale import at_speed
from mgpusim.sim.simulation import simulate
from mgpusim.studies import load_study, verdict
from mgpusim.studies import pipeline as pipeline
from mgpusim.studies.measuring import measured_folder
from mgpusim.validation.crossvalidate import validate_experiment

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "hardware_profiles" / "lavapipe_2core.toml"
RUNS = ROOT / "data" / "lavapipe" / "main_job_2026-11-25_8threads" / "runs"
WORK = {"pixel": 256 * 192, "pixel_iteration": 256 * 192 * 500}


def test_a_slower_host_costs_every_pass_and_copy_that_much_more():
    base = load_profile(PROFILE)
    slow = CostModel(at_speed(base, 2.0))
    fast = CostModel(base)
    assert slow.pass_ns(0, "fragment_loop", WORK) == pytest.approx(2 * fast.pass_ns(0, "fragment_loop", WORK), abs=1)
    assert slow.copy_setup_ns(0, "graphics", "d2h") == pytest.approx(2 * fast.copy_setup_ns(0, "graphics", "d2h"), abs=1)
    for path in ("d2h", "h2d", "d2d"):
        assert slow.link_bandwidth(0, path) * 2 == fast.link_bandwidth(0, path)
    assert slow.memcpy_thread_cap() * 2 == fast.memcpy_thread_cap()
    h, g = at_speed(base, 2.0).host, at_speed(base, 2.0).gpus[0]
    assert (h.submit_ns, h.dispatch_ns, g.task_gap_ns) == (2 * base.host.submit_ns, 2 * base.host.dispatch_ns,
                                                           2 * base.gpus[0].task_gap_ns)
    assert g.costs["mesh"].cpu_overhead_ns == pytest.approx(2 * base.gpus[0].costs["mesh"].cpu_overhead_ns)


def test_what_is_not_cpu_work_keeps_its_value():
    base = load_profile(PROFILE)
    slow = at_speed(base, 1.7)
    assert (slow.host.host_copy_wake_ns, slow.host.busy_wake_ns, slow.host.busy_wake_share) == (
        base.host.host_copy_wake_ns, base.host.busy_wake_ns, base.host.busy_wake_share)
    assert slow.host.oversubscribed_efficiency == base.host.oversubscribed_efficiency
    assert [c.cores for c in slow.gpus[0].costs.values()] == [c.cores for c in base.gpus[0].costs.values()]
    assert at_speed(base, 1.0) is base


def test_a_simulated_frame_takes_about_scale_times_longer():
    exp = load_study(LAVAPIPE_STUDY).calibration[0].load(PROFILE)
    one = simulate(exp).summary["frame_time_ms"]
    two = simulate(replace(exp, profile=at_speed(exp.profile, 2.0))).summary["frame_time_ms"]
    # everything but the kernel's wake latencies doubles
    assert 1.8 * one < two <= 2.0 * one + 1e-6


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf, 100.0])
def test_a_scale_that_is_no_speed_is_refused(scale):
    with pytest.raises(InputError, match="speed scale"):
        at_speed(load_profile(PROFILE), scale)


def test_a_profile_of_real_gpus_is_not_scaled():
    base = load_profile(PROFILE)
    real = replace(base, host=replace(base.host, gpus_share_cpu=False))
    with pytest.raises(InputError, match="gpus_share_cpu"):
        at_speed(real, 1.2)


def speed(before: float, after: float, other: float = 0.0) -> sn.RunSpeed:
    return sn.RunSpeed("c", "run0", before, after, 4.0, other, 0.0)


def test_a_run_speed_is_its_faster_probe_over_the_reference():
    """The compared window is the runs' fast end: the faster probe is the one that saw it."""
    s = speed(6.0, 9.0)
    assert s.probe_ms == pytest.approx(6.0) and s.ratio == pytest.approx(1.5)
    assert speed(9.0, 6.0).probe_ms == pytest.approx(6.0)
    s = speed(4.0, 9.0)
    assert s.disagreement == pytest.approx(1.25) and speed(9.0, 4.0).disagreement == pytest.approx(1.25)


def test_the_rule_flags_a_run_whose_probes_disagree_or_that_ran_beside_other_work():
    assert speed(4.0, 4.2).flag() == ""
    assert "speed moved 50% during the run" in speed(4.0, 6.0).flag()
    assert "other processes used 0.90 cores" in speed(4.0, 4.1, other=0.9).flag()
    assert speed(4.0, 4.1, other=math.nan).flag() == ""  # unknown load: only the probes judge


def test_the_reference_is_the_median_of_the_trusted_calibration_runs():
    table = pd.DataFrame([
        {"config": "a", "run": "run0", "before_ms": 4.0, "after_ms": 4.0, "other_cores": 0.0, "steal_cores": 0.0},
        {"config": "b", "run": "run1", "before_ms": 5.0, "after_ms": 5.0, "other_cores": 0.0, "steal_cores": 0.0},
        {"config": "c", "run": "run0", "before_ms": 9.0, "after_ms": 9.0, "other_cores": 1.0, "steal_cores": 0.0},
        {"config": "d", "run": "run0", "before_ms": 6.0, "after_ms": 6.0, "other_cores": 0.0, "steal_cores": 0.0}])
    assert sn.reference_ms(table, [("a", "run0"), ("b", "run1"), ("c", "run0")]) == pytest.approx(4.5)
    assert sn.reference_ms(table, [("c", "run0")]) == pytest.approx(9.0)  # none trusted: all
    assert sn.reference_ms(table, [("a", "run1")]) is None


@pytest.fixture
def probed_runs(tmp_path: Path) -> tuple[Path, dict[str, float]]:
    """The committed job's runs with a speed record: calibration runs at 4 ms, and two held-out
    runs, one at a slower (5 ms) steady machine and one whose speed moved during the run."""
    root = tmp_path / "runs"
    shutil.copytree(RUNS, root)
    study = load_study(LAVAPIPE_STUDY)
    probes = {e.name: (4.0, 4.0) for e in study.calibration}
    probes.update({"afr_3gpu": (5.0, 5.0), "afr_4gpu_128x96": (4.0, 6.0)})
    for name, (before, after) in probes.items():
        rows = [{"pass": "fragment_loop", "median_ms": before}, {"pass": "mesh", "median_ms": 2.0}]
        later = [{"pass": "fragment_loop", "median_ms": after}, {"pass": "mesh", "median_ms": 2.0}]
        run_speed.append(root / run_speed.FILE, run_speed.record(
            name, run_speed.compared_run(root, name), rows, later, {"other_cores": 0.0, "steal_cores": 0.0}))
    return root, {"afr_3gpu": 1.25, "afr_4gpu_128x96": 1.0}


def test_each_run_is_predicted_at_its_own_probe_ratio(probed_runs, tmp_path: Path):
    root, ratios = probed_runs
    study = load_study(LAVAPIPE_STUDY)
    speeds = pipeline.run_speeds(study, study.held_out, root, root)
    assert {n: s.ratio for n, s in speeds.items()} == pytest.approx(ratios)
    exp = next(e for e in study.held_out if e.name == "afr_3gpu").load(PROFILE)
    report = validate_experiment(exp, tmp_path / "v", measured_folder(root, "afr_3gpu"),
                                 speed=speeds["afr_3gpu"])
    sp = json.loads((tmp_path / "v" / "summary.json").read_text())["speed"]
    assert sp["probe_ratio"] == pytest.approx(1.25) and sp["flag"] == ""
    assert sp["simulated_frame_ms"] > 1.15 * report["simulated"]["frame_time_ms"]  # slower machine
    measured = report["measured"]["frame_time_ms"]
    assert sp["frame_time_error"] == pytest.approx(sp["simulated_frame_ms"] / measured - 1)


def test_held_out_runs_kept_apart_are_normalized_by_the_calibration_runs_speed(probed_runs, tmp_path: Path):
    """A study whose halves keep their runs in different folders: the held-out folder's speed
    records hold no calibration run, so the speed at calibration comes from the calibration
    folder's."""
    root, ratios = probed_runs
    study = load_study(LAVAPIPE_STUDY)
    table = run_speed.read(root / run_speed.FILE)
    calibration = {e.name for e in study.calibration}
    cal_root = tmp_path / "calibration_runs"
    cal_root.mkdir()
    table[table["config"].isin(calibration)].to_csv(cal_root / run_speed.FILE, index=False)
    table[~table["config"].isin(calibration)].to_csv(root / run_speed.FILE, index=False)
    assert pipeline.run_speeds(study, study.held_out, root, root) == {}  # no reference there
    speeds = pipeline.run_speeds(study, study.held_out, root, cal_root)
    assert {n: sp.ratio for n, sp in speeds.items()} == pytest.approx(ratios)


def test_one_command_reads_each_folders_speed_record_once(probed_runs, tmp_path: Path, monkeypatch):
    """`study validate --held-out`'s two halves and its report share the records: the
    calibration folder's is read once, not once per half and again for the report."""
    root, ratios = probed_runs
    study = load_study(LAVAPIPE_STUDY)
    cal_root = tmp_path / "calibration_runs"
    cal_root.mkdir()
    shutil.copy(root / run_speed.FILE, cal_root / run_speed.FILE)
    reads: list[Path] = []
    read = run_speed.read
    monkeypatch.setattr(run_speed, "read", lambda path: reads.append(path) or read(path))
    tables: pipeline.SpeedTables = {}
    pipeline.run_speeds(study, study.calibration, cal_root, cal_root, tables)
    speeds = pipeline.run_speeds(study, study.held_out, root, cal_root, tables)
    report_table = pipeline.speed_table(tables, cal_root)
    assert {n: sp.ratio for n, sp in speeds.items()} == pytest.approx(ratios)
    assert sorted(reads) == sorted([cal_root / run_speed.FILE, root / run_speed.FILE])
    assert report_table is tables[cal_root] and len(report_table) == len(read(root / run_speed.FILE))


def test_the_table_report_and_verdict_come_from_the_probes(probed_runs, tmp_path: Path):
    root, _ = probed_runs
    study = load_study(LAVAPIPE_STUDY)
    entries = tuple(e for e in study.held_out if e.name in ("afr_3gpu", "afr_4gpu_128x96"))
    table = pipeline.validate(study, entries, root, PROFILE, tmp_path / "v", lambda m: None)
    assert table["probe_ratio"].tolist() == pytest.approx([1.25, 1.0])
    assert table["speed_flag"].tolist()[0] == "" and "speed moved 50%" in table["speed_flag"].tolist()[1]
    path = pipeline.write_report(tmp_path, study, {pipeline.HELD_OUT_TITLE: table}, "fit",
                                 run_speeds=run_speed.read(root / run_speed.FILE))
    text = path.read_text()
    assert "| probe ratio | normalized error | band | speed flag |" in text
    assert "| 1.25 |" in text and "**flagged**: moved 50%" in text
    assert "## The machine's speed at each run" in text
    stats = json.loads((tmp_path / "errors.json").read_text())[pipeline.HELD_OUT_TITLE]
    # the flagged run stays in the verdict, its speed's movement in the prediction's band
    prediction = stats["verdict"]["prediction"]
    assert prediction["flagged_runs"] == 1 and prediction["errors"] == "speed-normalized"
    moved = table.index[table["config"] == "afr_4gpu_128x96"][0]
    err = table.loc[moved, "normalized_frame_time_error"]
    spread = table.loc[moved, "run_to_run_spread"]
    assert verdict.band(table).loc[moved, "hi"] == pytest.approx((1 + err) * 1.5 - 1)
    assert verdict.band(table).loc[moved, "lo"] == pytest.approx((1 + err) / (1 + spread) - 1)
    assert stats["normalized_median_abs_frame_time_error"] == pytest.approx(
        table["normalized_frame_time_error"].abs().median())
    assert text.startswith(f"# mgpusim study {study.name}: measured vs simulated\n\n**Verdict on the 2 "
                           "held-out configurations:")
    page = (tmp_path / "report.html").read_text()  # the page states the same as report.md
    assert "Verdict on the 2 held-out configurations" in page and "band" in page
    assert "probe ratio" in page and "moved 50%" in page
