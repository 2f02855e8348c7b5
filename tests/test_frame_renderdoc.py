"""RenderDoc captures (`.rdc`) in `mgpusim frame import`: two real captures made here on
lavapipe (tests/data/renderdoc/PROVENANCE.md): the runner's passes under debug labels, and a
frame of vkcube. Their replay records (what :mod:`mgpusim.frames.rdc_replay` printed for
them) test the conversion everywhere; the replay itself runs where RenderDoc's Python module
is installed."""
from __future__ import annotations

import json
import statistics
from pathlib import Path

import pytest

from mgpusim import load_experiment, simulate
from mgpusim.cli import main
from mgpusim.frames import rdc, rdc_replay
from mgpusim.frames.formats import slices_table
from mgpusim.frames.importer import frame_from_slices
from mgpusim.model.errors import InputError

DATA = Path(__file__).resolve().parent / "data" / "renderdoc"
DEFERRED, CUBE = DATA / "deferred_lavapipe.rdc", DATA / "vkcube_frame100.rdc"
PROFILE = Path(__file__).resolve().parents[1] / "hardware_profiles/pcie4_pair.toml"
LABELS = ["Shadow map", "GBuffer", "Lighting", "Particle update", "Particles", "Post"]

needs_renderdoc = pytest.mark.skipif(rdc_replay.module_path() is None,
                                     reason="RenderDoc's Python module is not installed (python3-renderdoc)")


def _record(capture: Path) -> dict:
    return json.loads(capture.with_suffix(".replay.json").read_text())


def _frame(record: dict, file: str = "x.rdc"):
    rows, meta = rdc.rows_from_record(record, file)
    frame = frame_from_slices(slices_table(rows), name="f", source=file, width=meta["width"],
                              height=meta["height"], read_notes=meta["notes"])
    return frame, meta


def test_labelled_passes_are_the_engines_passes_timed_by_their_actions():
    record = _record(DEFERRED)
    frame, meta = _frame(record)
    assert [p.name for p in frame.passes] == LABELS
    assert (meta["width"], meta["height"]) == (128, 96)  # the last pass's colour target
    assert frame.frames == record["replays"] == 5
    by_label = {a["markers"][-1]: a for a in record["actions"]}
    for p in frame.passes:  # one action each: its median GPU Duration over the replays
        assert p.gpu_ms == pytest.approx(statistics.median(by_label[p.name]["seconds"]) * 1e3, abs=1e-12)
    passes = {p.name: p for p in frame.passes}
    assert passes["Particles"].reads == ("Particle update",)  # the vertex buffer the update wrote
    written = record["resources"][str(by_label["Particles"]["reads"][0])]["bytes"]
    assert passes["Particle update"].output_bytes == written
    assert passes["Post"].output_bytes == 128 * 96 * 4  # presented: its colour target
    assert "replayed 5 time(s) on llvmpipe" in frame.notes[0]


def test_a_frame_without_labels_is_its_render_passes_at_the_swapchain_size():
    record = _record(CUBE)
    frame, meta = _frame(record)
    assert [p.name for p in frame.passes] == ["Render pass 1"]
    assert (meta["width"], meta["height"]) == (500, 500)  # vkcube's window: its swapchain image
    writes = record["actions"][0]["writes"]
    assert frame.passes[0].output_bytes == sum(record["resources"][str(w)]["bytes"] for w in writes)
    assert "frame 100" in frame.notes[0]


def test_an_imported_capture_runs_on_one_gpu_at_its_passes_sum(tmp_path):
    rows, meta = rdc.rows_from_record(_record(DEFERRED), "d.rdc")
    frame = frame_from_slices(slices_table(rows), name="d", source="d.rdc", width=meta["width"],
                              height=meta["height"])
    from mgpusim.frames.importer import check_experiment, experiment_text  # noqa: PLC0415
    out = tmp_path / "d.toml"
    out.write_text(experiment_text(frame, PROFILE, out))
    check_experiment(out.read_text(), out)
    trace = simulate(load_experiment(out)).trace
    renders = trace[(trace["step"] == "render") & (trace["frame"] == 20)]
    assert (renders["end_ns"] - renders["start_ns"]).sum() == pytest.approx(frame.gpu_ms * 1e6, abs=len(LABELS))


def test_without_renderdocs_module_the_import_says_how_to_get_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RENDERDOC_PYTHON_PATH", str(tmp_path))  # a folder without renderdoc.so
    assert main(["frame", "import", str(DEFERRED), "--out", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "deferred_lavapipe.rdc" in err[0] and "apt-get install python3-renderdoc" in err[0]
    assert not (tmp_path / "x.toml").exists()


@needs_renderdoc
def test_the_committed_capture_replays_to_its_record(tmp_path, capsys):
    """The replay here gives the committed record's passes, reads, sizes and resources; its
    times are this machine's (positive, not compared)."""
    out = tmp_path / "d.toml"
    assert main(["frame", "import", str(DEFERRED), "--out", str(out), "--profile", str(PROFILE)]) == 0
    assert "a Vulkan capture by RenderDoc" in capsys.readouterr().out
    passes = load_experiment(out).scene.passes
    want, _ = _frame(_record(DEFERRED))
    assert [p.name for p in passes] == LABELS
    assert [p.reads for p in passes] == [p.reads for p in want.passes]
    assert [p.params.get("output_bytes", 0) for p in passes] == [p.output_bytes for p in want.passes]
    assert all(p.params["gpu_ms"] > 0 for p in passes)
    got = rdc.replay_record(CUBE, replays=2)
    assert {k: v for k, v in got.items() if k not in ("actions", "replays", "replay_gpu")} == \
        {k: v for k, v in _record(CUBE).items() if k not in ("actions", "replays", "replay_gpu")}


def test_without_markers_passes_are_render_passes_and_a_dispatch_its_own():
    """The deferred capture's record with its labels taken away: the grouping rules alone."""
    record = _record(DEFERRED)
    for action in record["actions"]:
        action["markers"] = []
    frame, _ = _frame(record)
    assert [p.name for p in frame.passes] == ["Render pass 1", "Render pass 2", "Render pass 3",
                                              "vkCmdDispatch() (event 41)", "Render pass 4", "Render pass 5"]


def test_a_label_met_again_later_is_a_second_pass_and_no_work_is_refused():
    record = _record(DEFERRED)
    record["actions"][-1]["markers"] = ["Lighting"]  # Post's draw under a second Lighting label
    frame, _ = _frame(record)
    assert [p.name for p in frame.passes][-2:] == ["Particles", "Lighting#2"]
    with pytest.raises(InputError, match="no GPU work"):
        rdc.rows_from_record({**record, "actions": []}, "x.rdc")
