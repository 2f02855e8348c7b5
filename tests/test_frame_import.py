"""`mgpusim frame import`: captures in three formats become experiments of `captured` passes
that every schedule runs; bad captures are one line naming the file and the field."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim import load_experiment, simulate
from mgpusim.cli import main
from mgpusim.frames.formats import read_chrome, read_csv, read_run, slices_table
from mgpusim.frames.importer import exposed_times, frame_from_slices
from mgpusim.measure import run_archive
from mgpusim.model.errors import InputError
from mgpusim.model.scene import PassSpec, temporal_reads
from mgpusim.model.work_terms import pass_work

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "frames"
RUN = ROOT / "data/lavapipe/history/main_job_2026-11-25/runs/pipe_1gpu/steady"
PROFILE = ROOT / "hardware_profiles/pcie4_pair.toml"


def _import(capture: Path, out: Path, *extra: str) -> int:
    return main(["frame", "import", str(capture), "--out", str(out), "--profile", str(PROFILE), *extra])


def _passes(path: Path) -> dict[str, PassSpec]:
    return {p.name: p for p in load_experiment(path).scene.passes}


# ----- the captured pass ----------------------------------------------------------------------
def test_a_captured_pass_splits_its_pixel_share_by_pixels_and_the_rest_by_geometry():
    spec = PassSpec("p", "captured", {"gpu_ms": 4.0, "pixels": 1000, "pixel_share": 0.75})
    assert pass_work(spec, 1000)["reference_ns"] == pytest.approx(4e6)
    assert pass_work(spec, 500)["reference_ns"] == pytest.approx(4e6 * (0.25 + 0.75 / 2))  # a half tile
    assert pass_work(spec, 1000, 0.5)["reference_ns"] == pytest.approx(4e6 * (0.125 + 0.75))  # half the geometry


def test_sort_first_halves_a_pixel_bound_captured_frame(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms,pixel_share\nshade,graphics,10,1\n")
    out = tmp_path / "f.toml"
    assert _import(csv, out, "--size", "64x64") == 0
    one = simulate(load_experiment(out)).summary
    two = simulate(load_experiment(out, {"schedule": {"name": "sort_first", "gpus": 2}})).trace
    renders = two[two["step"] == "render"]
    assert renders["end_ns"].sub(renders["start_ns"]).max() == 5_000_000  # half the rows, half the time
    assert one["frame_time_ms"] > 10


# ----- CSV ------------------------------------------------------------------------------------
def test_csv_reads_resolve_to_producers_and_the_cpu_row_is_cpu_work(tmp_path):
    csv = tmp_path / "deferred.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes\n"
                   "game,cpu,4.5,,,\n"
                   "shadow,graphics,1.0,,shadowmap,4194304\n"
                   "gbuffer,graphics,2.0,,albedo;normal,8294400;8294400\n"
                   "ssao,compute,0.5,normal,ao,2073600\n"
                   "light,graphics,1.5,albedo;normal;ao;shadowmap;history,hdr,16588800\n"
                   "taa,graphics,0.4,hdr;history,history,8294400\n"
                   "upload,transfer,0.3,,,\n")
    out = tmp_path / "deferred.toml"
    assert _import(csv, out, "--size", "1920x1080") == 0
    passes = _passes(out)
    assert list(passes) == ["shadow", "gbuffer", "ssao", "light", "taa"]  # transfer work left out
    assert passes["light"].reads == ("gbuffer", "ssao", "shadow", "taa")  # history: taa's, last frame
    assert passes["gbuffer"].params["output_bytes"] == 2 * 8294400
    assert passes["taa"].params["output_bytes"] == 8294400  # read by light (next frame) and presented
    assert passes["ssao"].params["gpu_ms"] == 0.5
    exp = load_experiment(out)
    assert exp.schedule.cpu_frame_us == 4500
    assert temporal_reads(exp.scene) == [("light", "taa"), ("taa", "taa")]
    text = out.read_text()
    assert "ran on the compute queue" in text and "transfer-queue work left out" in text


def test_csv_frames_give_medians(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("frame,pass,queue,gpu_ms\n" + "".join(f"{f},a,graphics,{ms}\n{f},b,graphics,1\n"
                                                         for f, ms in enumerate([1.0, 3.0, 2.0])))
    slices, _ = read_csv(csv)
    frame = frame_from_slices(slices, name="f", source=str(csv), width=8, height=8)
    assert [(p.name, p.gpu_ms, p.frames) for p in frame.passes] == [("a", 2.0, 3), ("b", 1.0, 3)]


def test_a_stereo_csv_becomes_xr_with_one_eye_per_pass(tmp_path):
    out = tmp_path / "xr.toml"
    assert _import(EXAMPLES / "xr_two_views_lavapipe.csv", out, "--size", "192x192") == 0
    exp = load_experiment(out)
    assert (exp.schedule.name, exp.schedule.gpus, exp.schedule.opt("views")) == ("xr", 1, 2)
    assert [p.name for p in exp.scene.passes] == ["tori"]
    assert exp.scene.passes[0].param("pixel_share") == 0  # a mesh: its time goes with triangles


# ----- Chrome trace-event JSON ----------------------------------------------------------------
def test_our_own_perfetto_export_imports_as_the_run_it_came_from(tmp_path):
    """examples/frames: mgpusim's export of four frames of a committed run; the imported pass
    times are those frames' medians, the schedule's present left out."""
    slices, meta = read_chrome(EXAMPLES / "pipelining_lavapipe.perfetto.json")
    frame = frame_from_slices(slices, name="x", source="x", width=256, height=192,
                              left_out=meta["left_out"])
    trace = pd.read_parquet(RUN.parents[1] / "runs.parquet")
    trace = trace[trace["run"] == "pipe_1gpu/steady"]
    trace = trace[(trace["frame"] < trace["frame"].min() + 4) & (trace["step"] == "render")]
    want = ((trace["end_ns"] - trace["start_ns"]) / 1e6).groupby(trace["task"]).median()
    got = {p.name: p.gpu_ms for p in frame.passes}  # medians of whole ns: half a ns apart at most
    assert got == pytest.approx(dict(want.items()), abs=1e-9)
    assert any("present" in n for n in frame.notes)


def _chrome(path: Path, events: list) -> Path:
    path.write_text(json.dumps({"traceEvents": events}))
    return path


def _meta(pid: int, tid: int, process: str, thread: str) -> list[dict]:
    return [{"ph": "M", "name": "process_name", "pid": pid, "tid": 0, "args": {"name": process}},
            {"ph": "M", "name": "thread_name", "pid": pid, "tid": tid, "args": {"name": thread}}]


def test_chrome_groups_number_frames_and_args_carry_resources(tmp_path):
    events = _meta(1, 1, "GPU", "Direct queue") + _meta(2, 7, "Game", "main")
    for f in range(3):
        t0 = f * 20_000
        events += [{"ph": "X", "name": f"Frame {f}", "pid": 1, "tid": 1, "ts": t0, "dur": 12_000},
                   {"ph": "X", "name": "depth", "pid": 1, "tid": 1, "ts": t0, "dur": 4000,
                    "args": {"writes": ["depth"], "bytes": 8294400}},
                   {"ph": "B", "name": "light", "pid": 1, "tid": 1, "ts": t0 + 5000,
                    "args": {"reads": "depth", "writes": "hdr", "bytes": [16588800]}},
                   {"ph": "E", "pid": 1, "tid": 1, "ts": t0 + 11_000},
                   {"ph": "X", "name": "update", "pid": 2, "tid": 7, "ts": t0, "dur": 3000}]
    slices, _ = read_chrome(_chrome(tmp_path / "t.json", events))
    frame = frame_from_slices(slices, name="t", source="t", width=1920, height=1080)
    assert frame.frames == 3
    assert [(p.name, p.gpu_ms, p.reads, p.output_bytes) for p in frame.passes] == [
        ("depth", 4.0, (), 8294400), ("light", 6.0, ("depth",), 16588800)]
    assert frame.cpu_ms == 3.0


def test_a_run_folder_imports_its_scene_reads(tmp_path):
    slices, meta = read_run(RUN)
    assert (meta["width"], meta["height"]) == (256, 192)
    frame = frame_from_slices(slices, name="r", source=str(RUN), width=256, height=192)
    assert [p.reads for p in frame.passes] == [(), ("a",), ("a", "b"), ("a", "b", "c")]
    assert all(p.pixel_share == 1.0 for p in frame.passes)  # fragment loop and filters


# ----- bad captures ---------------------------------------------------------------------------
BAD = {
    "json syntax": ("t.json", '{"traceEvents": [', ["t.json", "not valid JSON"]),
    "negative dur": ("t.json", json.dumps({"traceEvents": _meta(1, 1, "gpu0", "graphics") + [
        {"ph": "X", "name": "a", "pid": 1, "tid": 1, "ts": 0, "dur": -3}]}), ["traceEvents[2].dur"]),
    "no gpu track": ("t.json", json.dumps({"traceEvents": [{"ph": "X", "name": "a", "pid": 1, "tid": 1,
                                                            "ts": 0, "dur": 3}]}), ["no GPU work"]),
    "unended begin": ("t.json", json.dumps({"traceEvents": _meta(1, 1, "gpu0", "graphics") + [
        {"ph": "B", "name": "a", "pid": 1, "tid": 1, "ts": 0}]}), ["traceEvents[2]", "never ended"]),
    "csv column": ("t.csv", "pass,gpu_ms\na,1\n", ["t.csv", "missing column(s) queue"]),
    "csv queue": ("t.csv", "pass,queue,gpu_ms\na,graphix,1\n", ["queue", "row 0"]),
    "csv time": ("t.csv", "pass,queue,gpu_ms\na,graphics,-1\n", ["gpu_ms", "row 0"]),
    "csv bytes": ("t.csv", "pass,queue,gpu_ms,writes,bytes\na,graphics,1,x;y,5\n", ["bytes (row 0)", "one per write"]),
    "csv share": ("t.csv", "pass,queue,gpu_ms,pixel_share\na,graphics,1,2\n", ["pixel_share (row 0)"]),
    "csv view missing": ("t.csv", "pass,queue,gpu_ms,view\na,graphics,1,0\nb,graphics,1,\n", ["pass 'b' has none"]),
    "empty csv": ("t.csv", "", ["t.csv", "empty"]),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_a_bad_capture_is_one_line_and_writes_nothing(case, tmp_path, capsys):
    name, text, expect = BAD[case]
    (tmp_path / name).write_text(text)
    out = tmp_path / "out.toml"
    capsys.readouterr()
    assert _import(tmp_path / name, out, "--size", "64x64") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    for words in expect:
        assert words in err[0], (words, err[0])
    assert not out.exists()


def test_a_sort_first_run_on_two_gpus_and_a_missing_size_are_refused(tmp_path, capsys):
    run = NATIVE / "sort_first_2gpu"
    assert _import(run, tmp_path / "x.toml") == 2
    assert "times each GPU's part of a pass" in capsys.readouterr().err
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\na,graphics,1\n")
    assert _import(csv, tmp_path / "x.toml") == 2
    assert "--size" in capsys.readouterr().err


# ----- measured runs: several GPUs, a study's folders ----------------------------------------
#: A study's committed runs (packed): per configuration run0/, run1/ and steady/.
NATIVE = ROOT / "data/lavapipe/main_job_2026-11-27_native/runs"


def _run_pass_ms(run: Path) -> dict[str, tuple[str, float]]:
    """Each render task's GPU and median time in a committed run, from its trace."""
    trace = run_archive.read_table(run / "trace.csv")
    renders = trace[trace["step"] == "render"]
    ms = ((renders["end_ns"] - renders["start_ns"]) / 1e6).groupby(renders["task"]).median()
    gpu = renders.groupby("task")["device"].first()
    return {str(t).removeprefix("render."): (str(gpu[t]), float(ms[t])) for t in ms.index}


def test_a_two_gpu_pipelining_run_imports_every_pass_where_it_ran(tmp_path, capsys):
    """The committed 2-GPU pipelining run (a and b on GPU 1, c and d on GPU 0): each pass at its
    median time on the GPU it ran on, the study's folder read as its steady window."""
    out = tmp_path / "p.toml"
    assert _import(NATIVE / "pipe_2gpu", out) == 0
    printed = capsys.readouterr().out
    assert "read steady/ of the study's run folder pipe_2gpu" in printed
    assert "gpu0: c, d; gpu1: a, b" in printed
    want = _run_pass_ms(NATIVE / "pipe_2gpu" / "steady")
    assert {n: p.params["gpu_ms"] for n, p in _passes(out).items()} == pytest.approx(
        {n: ms for n, (_, ms) in want.items()}, abs=1e-6)
    assert {g for g, _ in want.values()} == {"gpu0", "gpu1"}
    assert "a run of pipelining on 2 GPUs" in out.read_text()  # the note is in the file too


def test_a_two_gpu_afr_run_takes_each_gpus_frames(tmp_path):
    slices, meta = read_run(NATIVE / "afrt_2gpu" / "run0")
    trace = run_archive.read_table(NATIVE / "afrt_2gpu" / "run0" / "trace.csv")
    assert set(trace.loc[trace["step"] == "render", "device"]) == {"gpu0", "gpu1"}
    frame = frame_from_slices(slices, name="a", source="a", width=meta["width"], height=meta["height"])
    renders = trace[trace["step"] == "render"]
    assert frame.frames == renders["frame"].nunique()
    assert [p.name for p in frame.passes] == ["fragment_loop", "taa"]
    assert [p.reads for p in frame.passes] == [(), ("fragment_loop", "taa")]  # taa: its previous output
    assert not any("steady" in n for n in meta["notes"])  # run0 named: read as given


def test_a_two_gpu_xr_run_is_a_stereo_frame_of_one_eye_per_gpu(tmp_path, capsys):
    out = tmp_path / "xr.toml"
    assert _import(NATIVE / "xr_2gpu", out) == 0
    assert "each eye on a GPU of its own; gpu0: tori; gpu1: tori" in capsys.readouterr().out
    exp = load_experiment(out)
    assert (exp.schedule.name, exp.schedule.options["views"]) == ("xr", 2)
    trace = run_archive.read_table(NATIVE / "xr_2gpu" / "steady" / "trace.csv")
    renders = trace[trace["step"] == "render"]
    assert set(renders["device"]) == {"gpu0", "gpu1"}
    eye_ms = ((renders["end_ns"] - renders["start_ns"]) / 1e6).median()  # both eyes' slices
    assert exp.scene.passes[0].params["gpu_ms"] == pytest.approx(eye_ms, abs=1e-6)
    assert _import(NATIVE / "xr_4gpu_strong", tmp_path / "x4.toml") == 2  # a part of an eye per GPU
    assert "config.mode" in capsys.readouterr().err


def test_a_study_folder_without_steady_reads_run0_and_one_of_many_is_asked_for(tmp_path, capsys):
    study = tmp_path / "study"
    for name in ("run0", "run1"):
        folder = study / name
        folder.mkdir(parents=True)
        run_archive.read_table(RUN / "trace.csv").to_parquet(folder / "trace.parquet")
        (folder / "summary.json").write_text(run_archive.read_text(RUN / "summary.json"))
    out = tmp_path / "s.toml"
    assert _import(study, out) == 0
    assert "read run0/ of the study's run folder study: its first run" in capsys.readouterr().out
    assert _import(NATIVE, tmp_path / "all.toml") == 2
    err = capsys.readouterr().err
    assert "run(s) below" in err and "afr_2gpu/run0" in err and len(err.strip().splitlines()) == 1


def test_scene_reads_must_name_scene_passes(tmp_path):
    out = tmp_path / "f.toml"
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\nalpha,graphics,1\nbeta,graphics,1\n")
    assert _import(csv, out, "--size", "8x8") == 0
    with pytest.raises(InputError, match=r"scene.passes\[1\].reads: .*'alpah'.*did you mean 'alpha'"):
        load_experiment(out, {"scene.passes.1.reads": ["alpah"]})


def test_pipelining_waits_only_for_what_a_pass_reads(tmp_path):
    """Split after two passes: GPU 0's first pass reads only pass a, so it starts when a's copy
    arrived, not b's."""
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes\na,graphics,1,,A,1000000\n"
                   "b,graphics,4,,B,1000000\nc,graphics,1,a,C,100\nd,graphics,1,b;c,D,100\n")
    out = tmp_path / "f.toml"
    assert _import(csv, out, "--size", "64x64") == 0
    trace = simulate(load_experiment(out, {"schedule.gpus": 2, "schedule.split_at": 2})).trace
    frame = trace[trace["frame"] == 5].set_index("task")
    assert frame.loc["render.c", "start_ns"] < frame.loc["render.b", "end_ns"]
    assert frame.loc["render.d", "start_ns"] >= frame.loc["out.b.h2d", "end_ns"]
    assert frame.loc["out.a.d2h", "bytes"] == 1_000_000  # a's output, named by the pass's name


# ----- the output folder and the capture's size -----------------------------------------------
def test_out_is_a_folder_like_every_other_command(tmp_path, capsys):
    csv = tmp_path / "deferred.csv"
    csv.write_text("pass,queue,gpu_ms\nshade,graphics,2\n")
    folder = tmp_path / "frames"
    assert _import(csv, folder, "--size", "64x64") == 0
    assert (folder / "deferred.toml").is_file() and load_experiment(folder / "deferred.toml").name == "deferred"
    assert f"wrote {folder / 'deferred.toml'}" in capsys.readouterr().out
    assert _import(csv, folder, "--size", "64x64", "--name", "mine") == 0
    assert load_experiment(folder / "mine.toml").name == "mine"
    assert _import(csv, tmp_path / "exact.toml", "--size", "64x64") == 0  # the file form still works
    assert (tmp_path / "exact.toml").is_file()


def test_without_out_the_experiment_goes_to_out_stem(tmp_path, monkeypatch):
    csv = tmp_path / "deferred.csv"
    csv.write_text("pass,queue,gpu_ms\nshade,graphics,2\n")
    monkeypatch.chdir(tmp_path)
    assert main(["frame", "import", str(csv), "--size", "64x64", "--profile", str(PROFILE)]) == 0
    assert load_experiment(tmp_path / "out" / "deferred" / "deferred.toml").scene.width == 64


def test_a_folder_out_that_is_a_file_is_one_line(tmp_path, capsys):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\nshade,graphics,2\n")
    (tmp_path / "taken").write_text("")
    assert _import(csv, tmp_path / "taken", "--size", "64x64") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]


def test_a_csv_that_holds_its_size_needs_no_size_option(tmp_path, capsys):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms,width,height\nshade,graphics,2,2560,1440\npost,graphics,1,,\n")
    assert _import(csv, tmp_path) == 0
    exp = load_experiment(tmp_path / "f.toml")
    assert (exp.scene.width, exp.scene.height) == (2560, 1440)
    assert "(the capture's size)" in capsys.readouterr().out
    assert _import(csv, tmp_path / "g.toml", "--size", "64x32") == 0  # given, --size wins, with a note
    assert (load_experiment(tmp_path / "g.toml").scene.width, load_experiment(tmp_path / "g.toml").scene.height) == (64, 32)
    assert "the capture says 2560x1440; --size 64x32 wins" in capsys.readouterr().out


def test_a_chrome_trace_that_holds_its_size_needs_no_size_option(tmp_path):
    events = _meta(1, 1, "GPU", "graphics") + [{"ph": "X", "name": "shade", "pid": 1, "tid": 1, "ts": 0, "dur": 2000}]
    for meta in ({"width": 1280, "height": 720}, {"resolution": "1280x720"}):
        trace = tmp_path / "t.json"
        trace.write_text(json.dumps({"traceEvents": events, "metadata": meta}))
        assert _import(trace, tmp_path / "t.toml") == 0
        exp = load_experiment(tmp_path / "t.toml")
        assert (exp.scene.width, exp.scene.height) == (1280, 720)


@pytest.mark.parametrize("header,rows,words", [
    ("pass,queue,gpu_ms,width", "a,graphics,1,640", "width column without its pair"),
    ("pass,queue,gpu_ms,width,height", "a,graphics,1,640,480\nb,graphics,1,320,480", "one frame size"),
    ("pass,queue,gpu_ms,width,height", "a,graphics,1,0,480", "1..65536"),
])
def test_a_bad_size_in_the_capture_is_one_line(tmp_path, capsys, header, rows, words):
    csv = tmp_path / "f.csv"
    csv.write_text(f"{header}\n{rows}\n")
    assert _import(csv, tmp_path / "x.toml") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "f.csv" in err[0]
    assert not (tmp_path / "x.toml").exists()


# ----- what the capture corpus found (tests/test_corpus_captures.py has the whole corpus) -------
def test_epoch_microseconds_keep_every_nanosecond(tmp_path):
    """Times since 1970 in µs (1.7e15) are 1.7e18 ns, where a double is 256 ns coarse: the
    reader keeps times from the trace's first one, so a 1 µs pass stays 1 µs."""
    t0 = 1_700_000_000_000_000
    events = _meta(1, 1, "GPU", "graphics") + [
        {"ph": "B", "name": "a", "pid": 1, "tid": 1, "ts": t0}, {"ph": "E", "pid": 1, "tid": 1, "ts": t0 + 1},
        {"ph": "X", "name": "b", "pid": 1, "tid": 1, "ts": t0 + 1, "dur": 1.001}]
    slices, _ = read_chrome(_chrome(tmp_path / "t.json", events))
    assert list(slices["ms"]) == [0.001, 0.001001]
    bad = _meta(1, 1, "GPU", "graphics") + [{"ph": "X", "name": "a", "pid": 1, "tid": 1, "ts": 1.7e18, "dur": 1}]
    with pytest.raises(InputError, match=r"traceEvents\[2\].ts: .*written in ns"):
        read_chrome(_chrome(tmp_path / "ns.json", bad))


def test_gpu_ms_is_written_to_the_nanosecond(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\na,graphics,13.944869\nb,graphics,2\n")
    assert _import(csv, tmp_path / "f.toml", "--size", "8x8") == 0
    text = (tmp_path / "f.toml").read_text()
    assert "gpu_ms = 13.944869\n" in text and "gpu_ms = 2\n" in text  # six digits where they hold it


def test_a_repeated_pass_never_takes_the_name_of_a_captured_one(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\na,graphics,1\na,graphics,2\na#2,graphics,4\n")
    assert _import(csv, tmp_path / "f.toml", "--size", "8x8") == 0
    assert {n: p.params["gpu_ms"] for n, p in _passes(tmp_path / "f.toml").items()} == {
        "a": 1, "a#2_2": 2, "a#2": 4}


def test_names_and_paths_with_line_breaks_stay_inside_their_comments(tmp_path):
    """A newline in the capture's path, a track's name or a pass's name would end a comment
    of the experiment file and start a line of TOML."""
    events = _meta(1, 1, "GPU\nname = 1", "graphics\x7f") + _meta(2, 3, "Game", 'worker\n[scene]') + [
        {"ph": "X", "name": "p\nq\x7f", "pid": 1, "tid": 1, "ts": 0, "dur": 5},
        {"ph": "X", "name": "w", "pid": 2, "tid": 3, "ts": 0, "dur": 5}]
    trace = _chrome(tmp_path / "a\nb.json", events)
    assert _import(trace, tmp_path / "t.toml", "--size", "8x8") == 0
    assert list(_passes(tmp_path / "t.toml")) == ["p\nq\x7f"]
    assert "worker\\u000a[scene]" in (tmp_path / "t.toml").read_text()


def test_a_lone_surrogate_in_a_pass_name_is_refused_naming_the_event(tmp_path):
    trace = tmp_path / "t.json"
    trace.write_text(json.dumps({"traceEvents": _meta(1, 1, "GPU", "graphics") + [
        {"ph": "X", "name": "a\ud800", "pid": 1, "tid": 1, "ts": 0, "dur": 5}]}))
    with pytest.raises(InputError, match=r"traceEvents\[2\].name: .*surrogate"):
        read_chrome(trace)


def test_a_zero_length_slice_is_an_instant_not_a_group(tmp_path):
    events = _meta(1, 1, "GPU", "graphics") + [{"ph": "X", "name": "a", "pid": 1, "tid": 1, "ts": 0, "dur": 1000},
                                              {"ph": "X", "name": "mark", "pid": 1, "tid": 1, "ts": 0, "dur": 0}]
    slices, meta = read_chrome(_chrome(tmp_path / "t.json", events))
    assert list(slices["name"]) == ["a"] and "GPU/graphics: 1 zero-length slice(s)" in meta["left_out"]


@pytest.mark.parametrize("rows,words", [
    ("a,graphics,1,0\nb,graphics,1,0\n", "only view 0"),
    ("a,graphics,1,0\na,graphics,1,1\nb,graphics,1,0\n", "'b' of frame 0 is in view 0 but not in view 1"),
    ("a,graphics,1,0\na,graphics,1,0\nb,graphics,1,1\nb,graphics,1,1\n", "is in view 0 but not in view 1"),
])
def test_a_stereo_capture_needs_both_eyes_alike(tmp_path, capsys, rows, words):
    """The schedule runs each pass once per eye: a capture of one eye, or of eyes with other
    passes, would be run as if both eyes had them all."""
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms,view\n" + rows)
    assert _import(csv, tmp_path / "x.toml", "--size", "8x8") == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()


def test_csv_names_are_their_text_and_a_long_row_is_refused(tmp_path, capsys):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\n007,graphics,1\n7,graphics,1\nnan,graphics,1\n")
    assert _import(csv, tmp_path / "f.toml", "--size", "8x8") == 0
    assert list(_passes(tmp_path / "f.toml")) == ["007", "7", "nan"]
    csv.write_text("pass,queue,gpu_ms\na,graphics,1,5\n")  # pandas would shift it: pass 'graphics'
    assert _import(csv, tmp_path / "g.toml", "--size", "8x8") == 2
    assert "more fields than the header" in capsys.readouterr().err


def test_an_example_capture_is_found_from_any_folder(tmp_path, monkeypatch):
    """The README's `mgpusim frame import examples/frames/...` from a wheel install, where
    no checkout is around: the shipped copy (mgpusim/frames/examples) is read."""
    from mgpusim.frames.formats import EXAMPLES, resolve_capture
    monkeypatch.chdir(tmp_path)
    got = resolve_capture(Path("examples/frames/pipelining_lavapipe.csv"))
    assert got == EXAMPLES / "pipelining_lavapipe.csv" and got.is_file()
    assert resolve_capture(Path("examples/frames/none.csv")) == Path("examples/frames/none.csv")


# ----- async compute --------------------------------------------------------------------------
def _async_capture(path: Path, frames: int = 3) -> Path:
    """A graphics queue of gbuffer 4 ms, lighting 6 ms, post 2 ms back to back (frames marked
    there only) and an async-compute queue beside it: ssao 3 ms inside gbuffer + lighting,
    a simulation 4 ms of which 2 ms run after lighting, before post. The GPU is busy 14 ms a
    frame; the passes sum to 19 ms."""
    events = _meta(1, 1, "GPU", "Graphics queue") + _meta(1, 2, "GPU", "Async compute queue")
    for f in range(frames):
        t = f * 20_000
        events += [{"ph": "X", "name": f"Frame {f}", "pid": 1, "tid": 1, "ts": t, "dur": 14_000},
                   {"ph": "X", "name": "gbuffer", "pid": 1, "tid": 1, "ts": t, "dur": 4000},
                   {"ph": "X", "name": "lighting", "pid": 1, "tid": 1, "ts": t + 4000, "dur": 6000},
                   {"ph": "X", "name": "post", "pid": 1, "tid": 1, "ts": t + 12_000, "dur": 2000},
                   {"ph": "X", "name": "ssao", "pid": 1, "tid": 2, "ts": t + 3000, "dur": 3000},
                   {"ph": "X", "name": "sim", "pid": 1, "tid": 2, "ts": t + 8000, "dur": 4000}]
    return _chrome(path, events)


def test_async_compute_keeps_the_captures_frame_time_on_one_gpu(tmp_path, capsys):
    out = tmp_path / "a.toml"
    assert _import(_async_capture(tmp_path / "a.json"), out, "--size", "640x480") == 0
    printed = capsys.readouterr().out
    assert "async compute: 2 compute pass(es) overlapped graphics work (5.000 ms per frame hidden)" in printed
    passes = _passes(out)
    assert [(n, p.params["gpu_ms"]) for n, p in passes.items()] == [
        ("gbuffer", 4.0), ("ssao", 0.0), ("lighting", 6.0), ("sim", 2.0), ("post", 2.0)]
    assert "# ran 4 ms on the compute queue in the capture" in out.read_text()
    result = simulate(load_experiment(out))
    trace = result.trace
    present = trace[trace["step"] == "present"]
    present_ms = float((present["end_ns"] - present["start_ns"]).median()) / 1e6
    assert result.summary["frame_time_ms"] == pytest.approx(14.0 + present_ms, abs=1e-6)  # not 19


def test_an_async_compute_track_takes_its_frames_from_the_graphics_queue(tmp_path):
    slices, _ = read_chrome(_async_capture(tmp_path / "a.json", frames=4))
    compute = slices[slices["queue"] == "compute"]
    assert sorted(compute["frame"]) == [0, 0, 1, 1, 2, 2, 3, 3]
    frame = frame_from_slices(slices, name="a", source="a", width=64, height=64)
    assert frame.frames == 4 and all(p.frames == 4 for p in frame.passes)


@pytest.mark.parametrize("seed", range(20))
def test_graphics_and_cut_compute_slices_add_up_to_the_gpus_busy_time(seed):
    """Random slices on a graphics and a compute queue, each queue's in turn with gaps (the two
    overlapping anyhow, across frames too): the graphics slices keep their time, and with the
    compute slices cut they add up to the length of the union of all slices, to 1 ns a slice."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    queue = rng.choice(["graphics", "compute"], n)
    start, end = np.zeros(n), np.zeros(n)
    for q in ("graphics", "compute"):
        on = np.flatnonzero(queue == q)
        gaps, lengths = rng.integers(0, 3_000_000, len(on)), rng.integers(0, 8_000_000, len(on))
        start[on] = np.cumsum(gaps + np.concatenate(([0], lengths[:-1])))
        end[on] = start[on] + lengths
    slices = slices_table([{"frame": int(rng.integers(0, 3)), "queue": q, "name": f"p{i}", "ms": (b - a) / 1e6,
                            "start_ns": a, "end_ns": b, "reads": (), "writes": (), "bytes": (), "view": -1,
                            "pixel_share": math.nan} for i, (q, a, b) in enumerate(zip(queue, start, end))])
    cut = exposed_times(slices)
    graphics = cut["queue"] == "graphics"
    assert (cut.loc[graphics, "ms"] == slices.loc[graphics, "ms"]).all()
    assert (cut["ms"] <= cut["ran_ms"]).all() and (cut["ms"] >= 0).all()
    busy, reach = 0.0, -math.inf
    for a, b in sorted(zip(start, end)):  # the union, by a sweep
        busy += max(0.0, b - max(a, reach))
        reach = max(reach, b)
    if graphics.any():
        assert cut["ms"].sum() * 1e6 == pytest.approx(busy, abs=n)
    else:  # nothing to hide behind: a compute-only capture runs as captured
        assert (cut["ms"] == slices["ms"]).all()


def test_compute_rows_without_times_are_not_cut(tmp_path):
    csv = tmp_path / "f.csv"
    csv.write_text("pass,queue,gpu_ms\ngbuffer,graphics,4\nssao,compute,3\n")
    slices, _ = read_csv(csv)
    frame = frame_from_slices(slices, name="f", source="f", width=64, height=64)
    assert [(p.name, p.gpu_ms, p.ran_ms) for p in frame.passes] == [("gbuffer", 4.0, None), ("ssao", 3.0, None)]
