"""`mgpusim advise` and its output folder: one advise at a time in a folder, a killed run leaves
no report that reads as complete, a rerun gives the same advice; frames past the pass limit
refused before any work; progress reported in every stage of the search; one set of workers
serving every stage, with work done alongside the timelines."""
from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mgpusim.advise.advisor import LINKS, MAX_PASSES, check_frame, run_options, search
from mgpusim.advise.report import OUTPUTS, STAGING, write_advice
from mgpusim.advise.worker_set import GC_THRESHOLD, Workers, fewer_collections
from mgpusim.cli import main
from mgpusim.io.out_folder import LOCK_FILE
from mgpusim.io.progress import Stages

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "hardware_profiles" / "pcie4_pair.toml"
#: A small search (two GPUs, no timelines but the baseline's), a few seconds on one worker.
SMALL = ["--max-gpus", "2", "--timelines", "0", "--workers", "1", "--confirm", "4"]


def import_frame(folder: Path, rows: list[str], name: str = "f") -> Path:
    """A frame imported from CSV rows (pass,queue,gpu_ms,reads,writes,bytes,pixel_share)."""
    csv = folder / f"{name}.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n" + "".join(r + "\n" for r in rows))
    out = folder / f"{name}.toml"
    assert main(["frame", "import", str(csv), "--size", "1920x1080", "--profile", str(PROFILE),
                 "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> tuple[Path, Path]:
    """Two different frames: each advice says which it was."""
    tmp = tmp_path_factory.mktemp("frames")
    first = import_frame(tmp, ["shadow,graphics,1.5,,shadowmap,4194304,0",
                               "light,graphics,2.0,shadowmap,hdr,16588800,1",
                               "post,graphics,0.8,hdr,ldr,8294400,1"], "first")
    second = import_frame(tmp, ["gbuffer,graphics,3.0,,gb,16588800,0.6",
                                "light,graphics,1.0,gb,hdr,16588800,1"], "second")
    return first, second


def advise(frame: Path, out: Path) -> list[str]:
    """The advise command line of `frame` into `out`, as a subprocess runs it."""
    return [sys.executable, "-m", "mgpusim", "advise", str(frame), "--out", str(out), *SMALL]


def visible(out: Path) -> list[str]:
    """The files of `out` a reader sees (not the lock, not a run's staging folder)."""
    return sorted(p.name for p in out.iterdir() if not p.name.startswith("."))


def holding(out: Path, proc: subprocess.Popen, timeout_s: float = 120) -> None:
    """Wait until `proc` holds `out` and has removed the earlier advice (what it does first,
    before its search)."""
    lock, deadline = out / LOCK_FILE, time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the advise ended before it was seen holding its folder"
        if lock.is_file() and lock.read_text().strip() == str(proc.pid) and not visible(out):
            return
        time.sleep(0.01)
    pytest.fail(f"advise did not take {out} within {timeout_s} s")


def test_a_second_advise_is_refused_a_killed_one_leaves_no_report_a_rerun_the_same(frames, tmp_path, capsys):
    first, second = frames
    out = tmp_path / "advice"
    assert main(["advise", str(first), "--out", str(out), *SMALL]) == 0
    reference = (out / "advice.csv").read_bytes()
    assert visible(out) == sorted(OUTPUTS)
    capsys.readouterr()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(advise(second, out), env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        holding(out, proc)
        # a second advise into the same folder meanwhile: refused at once, in one line
        assert main(["advise", str(first), "--out", str(out), *SMALL]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"another mgpusim is writing {out} (pid {proc.pid})" in err[0], err
        proc.send_signal(signal.SIGKILL)  # mid-search: no handler runs
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # neither the first frame's report nor any file of either set is left to read as the answer
    assert visible(out) == []
    assert main(["advise", str(first), "--out", str(out), *SMALL]) == 0
    assert (out / "advice.csv").read_bytes() == reference
    assert visible(out) == sorted(OUTPUTS) and not (out / STAGING).exists()


def test_a_frame_past_the_pass_limit_is_refused_before_any_work(tmp_path, capsys):
    rows = [f"p{k},graphics,0.05,{f'p{k - 1}' if k else ''},p{k},8294400,1" for k in range(MAX_PASSES + 1)]
    frame = import_frame(tmp_path, rows, "many")
    capsys.readouterr()
    out = tmp_path / "advice"
    assert main(["advise", str(frame), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"up to {MAX_PASSES} passes, this one has {MAX_PASSES + 1}" in err[0], err
    assert "scene.passes" in err[0] and not out.exists()
    assert check_frame(frame, max_gpus=1).scene.passes  # one GPU: no pipelining, nothing refused


def test_an_earlier_advice_is_kept_when_the_input_is_bad(frames, tmp_path, capsys):
    first, _ = frames
    out = tmp_path / "advice"
    assert main(["advise", str(first), "--out", str(out), *SMALL]) == 0
    before = (out / "report.html").read_bytes()
    assert main(["advise", str(first), "--out", str(out), "--max-gpus", "0"]) == 2
    assert (out / "report.html").read_bytes() == before


def test_every_stage_reports_its_progress_to_the_end(frames):
    first, _ = frames
    seen: dict[str, list[tuple[int, int]]] = {}
    search(first, max_gpus=2, links=LINKS[:1], workers=1, confirm=2,
           progress=lambda stage, done, total: seen.setdefault(stage, []).append((done, total)))
    assert {"analytic level", "full fidelity"} <= set(seen)
    for stage, calls in seen.items():
        dones = [d for d, _ in calls]
        assert dones == sorted(dones) and calls[0][0] == 0 and calls[-1][0] == calls[-1][1] > 0, stage


def test_spread_over_workers_the_rows_come_back_in_order(frames):
    first, _ = frames
    items = [(k, {"schedule.frames": 20 + k}) for k in range(9)]
    one = run_options(str(first), {}, items, "analytic", 1)
    two = run_options(str(first), {}, items, "analytic", 2)
    strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert strip(two) == strip(one) and [r["option"] for r in two] == list(range(9))


def test_the_progress_has_one_bar_per_stage_each_to_its_end():
    stages = Stages("advise")  # drawn only after a second: nothing shows here
    stages("analytic level", 0, 10)
    first = stages.bar
    stages("analytic level", 10, 10)
    assert stages.bar is first and (first.n, first.total) == (10, 10)
    stages("full fidelity", 3, 4)  # a new stage: the last bar closed, a new one drawn
    assert stages.bar is not first and (stages.bar.n, stages.bar.total) == (3, 4)
    assert stages.bar.desc == "advise: full fidelity"
    with stages:
        pass
    assert stages.bar is None and stages.stage is None


def _results(advice) -> str:
    """An advice's table without the columns that time it, as CSV (NaN equal to NaN)."""
    return advice.table.drop(columns=[c for c in advice.table if c.endswith("wall_s")]).to_csv()


def test_one_set_of_workers_serves_every_stage_and_the_next_search(frames):
    first, second = frames
    here = [search(f, max_gpus=2, links=LINKS[:1], workers=1, confirm=2) for f in (first, second)]
    with Workers(2) as workers:
        kept = [search(f, max_gpus=2, links=LINKS[:1], workers=workers, confirm=2) for f in (first, second)]
        assert workers._pool is not None  # the processes of the first search served the second
    assert [_results(a) for a in kept] == [_results(a) for a in here]
    assert [a.counts["workers"] for a in kept] == [2, 2]


def test_work_alongside_the_timelines_is_in_the_answer(frames, tmp_path):
    first, _ = frames
    advice = search(first, max_gpus=2, links=LINKS[:1], workers=1, confirm=2)
    calls: list[int] = []

    def alongside() -> None:  # as the command checks the assumed shares while they are drawn
        calls.append(len(list((tmp_path / STAGING).glob("*.csv"))))
        advice.notes.append("checked alongside the timelines")
    with Workers(2) as workers:
        files = write_advice(advice, tmp_path, "first.toml", timelines=1, workers=workers, alongside=alongside)
    answer = json.loads(files["answer"].read_text())
    assert calls == [1] and "checked alongside the timelines" in answer["notes"]
    assert [t["option"] for t in answer["timelines"]][0] == 0 and len(answer["timelines"]) == 2
    assert all((tmp_path / t["timeline"]).is_file() and (tmp_path / t["perfetto"]).is_file()
               for t in answer["timelines"])


def test_the_collector_runs_less_often_only_while_a_command_searches(frames, tmp_path):
    before = gc.get_threshold()
    with fewer_collections():
        assert gc.get_threshold()[0] == GC_THRESHOLD and gc.get_freeze_count() > 0
    assert gc.get_threshold() == before
    first, _ = frames
    assert main(["advise", str(first), "--out", str(tmp_path / "a"), *SMALL]) == 0
    assert gc.get_threshold() == before  # the command gives the test's process its settings back
