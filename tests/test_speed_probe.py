"""The report's account of the machine's speed during a job (the probes' arithmetic)."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mgpusim.measure import speed_probe as speed
from mgpusim.model.errors import InputError, UnsteadyMachineError


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


class FakeTime:
    """A clock that moves only when slept on."""

    def __init__(self) -> None:
        self.now, self.slept = 0.0, []

    def clock(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.now += s


def test_waiting_tries_again_until_the_machine_is_steady():
    said: list[str] = []
    t = FakeTime()
    # two drifting tries of 3 checks, then a steady one
    rows = speed.wait_steady(8, 0.1, 30, said.append, retry_pause_s=60, checks=3, pause_s=0,
                             probe=fake_probe([2.0, 3.0, 2.0, 2.0, 2.6, 2.0, 2.0, 2.1, 2.05]),
                             clock=t.clock, sleep=t.sleep)
    assert [r["median_ms"] for r in rows if r["pass"] == "mesh"] == [2.0, 2.1, 2.05]
    assert t.slept == [60, 60]
    waits = [m for m in said if m.startswith("not steady yet")]
    assert waits == [
        "not steady yet: the mesh probe took 2.00-3.00 ms over 3 checks (50%, more than the 10% "
        "allowed by --steady-check); next try in 60 s (0 of 30 minutes waited)",
        "not steady yet: the mesh probe took 2.00-2.60 ms over 3 checks (30%, more than the 10% "
        "allowed by --steady-check); next try in 60 s (1 of 30 minutes waited)"]
    assert said[-1] == "steady: every probe within 5%"


def test_waiting_gives_up_when_its_time_is_spent():
    t = FakeTime()
    with pytest.raises(UnsteadyMachineError,
                       match=r"mesh probe took 2.00-4.00 ms .* \(still after 3 tries over 2 of "
                             r"the 2.5 minutes allowed by --wait-steady\)"):
        speed.wait_steady(8, 0.1, 2.5, lambda m: None, retry_pause_s=60, checks=2, pause_s=0,
                          probe=fake_probe([2.0, 4.0] * 10), clock=t.clock, sleep=t.sleep)
    assert t.slept == [60, 60]


@pytest.mark.parametrize("minutes", [0, -1, 24 * 60 + 1])
def test_waiting_refuses_a_wait_it_cannot_keep(minutes):
    with pytest.raises(InputError, match="expected minutes to wait"):
        speed.wait_steady(8, 0.1, minutes, lambda m: None, probe=fake_probe([]))


def test_the_main_job_refuses_to_wait_without_a_check(tmp_path: Path, capsys):
    from mgpusim.cli import main
    out = tmp_path / "job"
    assert main(["main", "--wait-steady", "5", "--out", str(out)]) == 2
    assert "--wait-steady waits for --steady-check to pass" in capsys.readouterr().err
    assert not out.exists()
