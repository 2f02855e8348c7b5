"""vmgpu's output read into frame times, on excerpts of real runs (tests/data/vmgpu/): the frame
lines, the GPUs and triangles, the checks that refuse a failed run, the stalls and the summary."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim.vmgpu import logs
from mgpusim.vmgpu.failures import RunFailedError

DATA = Path(__file__).parent / "data" / "vmgpu"
SINGLE = DATA / "single-x1-100000-640x480.log"
SORT_LAST = DATA / "sort-last-x2-100000-640x480.log"
SORT_FIRST = DATA / "sort-first-x4-100000-1024x768.log"
MEAN = DATA / "mean-every-10-single-x1-100000-640x480.log"
CRASH = DATA / "crash-without-basic-mode.log"
NO_DISPLAY = DATA / "no-x-display.log"
#: What the crashed run's process returned (vmgpu without -b on a mesh without materials).
CRASH_RETURNCODE = -11
#: ... and the run without an X server (Qt aborts).
NO_DISPLAY_RETURNCODE = -6


def text(path: Path) -> str:
    return path.read_text()


@pytest.mark.parametrize(("path", "gpus"), [(SINGLE, 1), (SORT_LAST, 2), (SORT_FIRST, 4)])
def test_a_real_run_parses_into_every_frame(path, gpus):
    log = logs.parse(text(path))
    assert log.frames["frame"].tolist() == list(range(200))
    assert log.frames_done == 200
    assert len(log.gpus) == gpus and all(g.startswith("llvmpipe") for g in log.gpus)
    assert log.triangles == 100_000
    assert len(log.fps) >= 3  # bpQt's carriage-return prints every 50 frames, split off
    frames = log.frames
    assert (frames["period_ms"] > 0).all()
    # busy time starts after the previous present ended, so it never exceeds the period
    assert (frames["busy_ms"] <= frames["period_ms"] + 1e-3).all()
    assert (frames["cpu_ms"] >= 0).all()


def test_the_mean_lines_count_their_frames():
    log = logs.parse(text(MEAN))
    assert (log.frames["frames_in_line"] == 10).all()
    assert int(log.frames["frames_in_line"].sum()) == log.frames_done == 200
    assert log.frames["frame"].tolist() == list(range(9, 200, 10))


def test_a_bare_frame_line_is_read_with_unknown_busy_and_cpu():
    log = logs.parse("frame_ms 0 12.5\nframe_ms 1 13.0\nframes_done 2\n")
    assert log.frames["period_ms"].tolist() == [12.5, 13.0]
    assert log.frames["busy_ms"].isna().all()


def test_a_run_as_asked_passes_the_check():
    log = logs.check("r1", 0, text(SORT_LAST), logs.Expected(frames=200, gpus=2, triangles=100_000))
    assert len(log.frames) == 200


def test_a_real_crash_is_one_clear_error_naming_the_run():
    with pytest.raises(RunFailedError, match=r"run 7/9 \(x\) failed: it was killed by SIGSEGV") as err:
        logs.check("7/9 (x)", CRASH_RETURNCODE, text(CRASH), logs.Expected(200, 1, 100_000))
    assert err.value.run == "7/9 (x)"
    assert "Loading meshes" in err.value.tail  # the run's last output comes with it


def test_a_run_without_an_x_server_is_refused_with_qts_words():
    with pytest.raises(RunFailedError, match="killed by SIGABRT") as err:
        logs.check("r", NO_DISPLAY_RETURNCODE, text(NO_DISPLAY), logs.Expected(200, 1, 100_000))
    assert "could not connect to display" in err.value.tail


def test_a_run_that_printed_nothing_is_refused():
    with pytest.raises(RunFailedError, match="printed no frame times"):
        logs.check("r", 0, "", logs.Expected(200, 1, 100_000))


def test_a_non_zero_exit_is_refused_even_with_frames():
    with pytest.raises(RunFailedError, match="exited with status 1"):
        logs.check("r", 1, text(SINGLE), logs.Expected(200, 1, 100_000))


def test_a_run_cut_short_is_refused():
    lines = text(SINGLE).splitlines()
    cut = "\n".join(line for line in lines if not line.startswith("frames_done")
                    and not (line.startswith("frame_ms ") and int(line.split()[1]) >= 120))
    with pytest.raises(RunFailedError, match="printed 120 frame times and frames_done None"):
        logs.check("r", 0, cut, logs.Expected(200, 1, 100_000))


def test_another_gpu_count_or_mesh_is_refused():
    with pytest.raises(RunFailedError, match="opened 2 GPUs, 3 were asked for"):
        logs.check("r", 0, text(SORT_LAST), logs.Expected(200, 3, 100_000))
    with pytest.raises(RunFailedError, match="loaded 100000 triangles, the mesh has 99999"):
        logs.check("r", 0, text(SORT_LAST), logs.Expected(200, 2, 99_999))


def test_a_stall_is_a_frame_over_five_times_the_median():
    frames = logs.parse(text(SINGLE)).frames
    assert not logs.stalls(frames["period_ms"]).any()
    slowed = frames.copy()
    slowed.loc[100, "period_ms"] = 6 * frames["period_ms"].median()
    slowed.loc[101, "period_ms"] = 4 * frames["period_ms"].median()
    assert logs.stalls(slowed["period_ms"]).tolist().count(True) == 1
    stats = logs.summary(slowed, warmup=20)
    assert stats["stalls"] == 1
    assert stats["stall_ms"] == pytest.approx(slowed.loc[100, "period_ms"])


def test_the_summary_leaves_the_warmup_out():
    frames = logs.parse(text(SORT_FIRST)).frames
    stats = logs.summary(frames, warmup=20)
    kept = frames.loc[frames["frame"] >= 20, "period_ms"]
    assert stats["frames_measured"] == 180
    assert stats["median_ms"] == pytest.approx(kept.median())
    assert stats["q25_ms"] <= stats["median_ms"] <= stats["q75_ms"]
    assert stats["iqr_ms"] == pytest.approx(stats["q75_ms"] - stats["q25_ms"])
    assert stats["fps_median"] == pytest.approx(1000 / stats["median_ms"])
    with pytest.raises(ValueError, match="no frames after the first 200"):
        logs.summary(frames, warmup=200)
