"""Worker processes: how many a command forks, and that spreading work keeps its order."""
from __future__ import annotations

import os

import pytest

from mgpusim.io.workers import in_workers, worker_count
from mgpusim.model.errors import InputError


def test_workers_follow_the_cores_the_jobs_and_the_cap(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("os.sched_getaffinity", lambda _pid: {0, 1, 2, 3})
    monkeypatch.delenv("MGPUSIM_WORKERS", raising=False)
    assert worker_count(10) == 4
    assert worker_count(3) == 3
    assert worker_count(0) == 1
    monkeypatch.setenv("MGPUSIM_WORKERS", "2")
    assert worker_count(10) == 2
    monkeypatch.setenv("MGPUSIM_WORKERS", "16")
    assert worker_count(10) == 4


@pytest.mark.parametrize("raw", ["0", "-1", "two", "1.5"])
def test_a_bad_cap_is_one_error_naming_the_variable(monkeypatch: pytest.MonkeyPatch, raw: str) -> None:
    monkeypatch.setenv("MGPUSIM_WORKERS", raw)
    with pytest.raises(InputError, match="MGPUSIM_WORKERS"):
        worker_count(4)


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def test_work_in_workers_comes_back_in_the_jobs_order(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("os.sched_getaffinity", lambda _pid: {0, 1})
    monkeypatch.delenv("MGPUSIM_WORKERS", raising=False)
    spread = list(in_workers(_square_and_pid, [(x,) for x in range(12)]))
    assert [r for r, _ in spread] == [x * x for x in range(12)]
    assert os.getpid() not in {pid for _, pid in spread}  # forked workers did it
    monkeypatch.setenv("MGPUSIM_WORKERS", "1")
    here = list(in_workers(_square_and_pid, [(x,) for x in range(12)]))
    assert [r for r, _ in here] == [r for r, _ in spread] and {pid for _, pid in here} == {os.getpid()}
