"""The report's account of the machine's speed during a job (the probes' arithmetic)."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.errors import InputError, UnsteadyMachineError
from mgpusim.study import speed


def probes(mesh_ms: list[float]) -> pd.DataFrame:
    points = [f"p{i}" for i in range(len(mesh_ms))]
    rows = [{"point": p, "pass": "fragment_loop", "median_ms": 4.0, "unix_time": 0} for p in points]
    rows += [{"point": p, "pass": "mesh", "median_ms": ms, "unix_time": 0} for p, ms in zip(points, mesh_ms)]
    return pd.DataFrame(rows, columns=speed.COLUMNS)


def test_drift_is_relative_to_the_first_probe_in_job_order():
    rel = speed.drift(probes([2.0, 3.0, 2.5]))
    assert list(rel.index) == ["p0", "p1", "p2"]
    assert rel["mesh"].tolist() == pytest.approx([1.0, 1.5, 1.25])
    assert rel["fragment_loop"].tolist() == pytest.approx([1.0, 1.0, 1.0])
    assert speed.worst_drift(probes([2.0, 3.0, 2.5])) == (pytest.approx(0.5), "mesh")


def test_the_report_warns_only_when_the_machine_moved():
    moved = "\n".join(speed.report_lines(probes([2.0, 4.0])))
    assert "Warning: the machine's speed moved" in moved and "mesh probe by 100%" in moved
    assert speed.drift_warning(probes([2.0, 4.0])) is not None
    assert speed.drift_warning(probes([2.0, 2.1])) is None
    steady = "\n".join(speed.report_lines(probes([2.0, 2.1])))
    assert "Warning" not in steady and "within 5%" in steady
    assert speed.report_lines(speed.read_probes([])) == []


def test_probe_tables_grow_and_read_back_in_order(tmp_path: Path):
    path = tmp_path / speed.FILE
    speed.append_probe(path, probes([2.0]).to_dict("records"))
    speed.append_probe(path, probes([3.0]).assign(point="later").to_dict("records"))
    both = speed.read_probes([tmp_path / "missing.csv", path])
    assert both["point"].tolist() == ["p0", "p0", "later", "later"]


def fake_probe(mesh_ms: list[float]):
    """A probe whose mesh takes the next of `mesh_ms` each time (the fragment loop 4 ms)."""
    times = iter(mesh_ms)

    def probe(point: str, threads: int | None) -> list[dict]:
        return [{"point": point, "pass": "fragment_loop", "median_ms": 4.0, "unix_time": 0},
                {"point": point, "pass": "mesh", "median_ms": next(times), "unix_time": 0}]
    return probe


def test_a_steady_machine_passes_the_check_with_its_probes():
    said: list[str] = []
    rows = speed.check_steady(8, 0.1, said.append, checks=3, pause_s=0,
                              probe=fake_probe([2.0, 2.1, 2.05]))
    assert [r["point"] for r in rows if r["pass"] == "mesh"] == [
        "steadiness check 1 of 3", "steadiness check 2 of 3", "steadiness check 3 of 3"]
    assert said[-1] == "steady: every probe within 5%"


def test_a_drifting_machine_stops_the_job_naming_the_pass_and_its_times():
    with pytest.raises(UnsteadyMachineError, match=r"mesh probe took 2.00-3.00 ms over 3 checks \(50%"):
        speed.check_steady(8, 0.1, lambda m: None, checks=3, pause_s=0,
                           probe=fake_probe([2.0, 3.0, 2.5]))


@pytest.mark.parametrize("threads, limit, what", [(None, 0.1, "needs a lavapipe study"),
                                                   (8, 0.0, "expected a fraction"),
                                                   (8, 10.0, "expected a fraction")])
def test_the_check_refuses_what_it_cannot_judge(threads, limit, what):
    with pytest.raises(InputError, match=what):
        speed.check_steady(threads, limit, lambda m: None, checks=2, pause_s=0,
                           probe=fake_probe([2.0, 2.0]))
