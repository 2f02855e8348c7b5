"""Case studies (`mgpusim case`): every shipped case runs, its derived quantities agree with the
simulated traces, bad cases are one clear error, and each case's lavapipe study loads."""
from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import cli
from mgpusim.cases.case_file import (
    COMPARISON,
    Case,
    CaseResult,
    amdahl_gain,
    calibrate,
    case_names,
    comparison,
    comparison_markdown,
    copy_limited_fps,
    docs_block,
    extrapolation,
    extrapolation_markdown,
    load_case,
    markdown,
    metric,
    parameter_overrides,
    run_case,
    sections_rendered,
    span_ms,
    steady,
    table,
    with_docs_block,
)
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import mesh_placement
from mgpusim.sim.simulation import simulate
from mgpusim.studies.study_file import load_study

ROOT = Path(__file__).resolve().parents[1]
CASES = ("dx12_pipelining", "particle_offload", "vulkan_thesis", "xr_stereo")
FRAMES = 16


@pytest.fixture(scope="module")
def results() -> dict[str, CaseResult]:
    return {name: run_case(load_case(name), frames=FRAMES) for name in CASES}


def test_the_four_cases_are_shipped():
    assert case_names() == list(CASES)


@pytest.mark.parametrize("name", CASES)
def test_every_run_simulates_and_is_tabled(results, name):
    cr = results[name]
    df = table(cr)
    assert list(df["run"]) == [r.name for r in cr.case.runs]
    simulated = df[[r.simulate for r in cr.case.runs]]
    assert len(simulated) and (simulated["frame time (ms)"] > 0).all()
    assert ((simulated["fps"] * simulated["frame time (ms)"] - 1000).abs() < 1e-6 * 1000).all()
    assert df[[not r.simulate for r in cr.case.runs]]["fps"].isna().all()
    text = markdown(cr)
    assert all(r.label in text for r in cr.case.runs)
    assert all(d.label in text for d in cr.case.derived)


@pytest.mark.parametrize("name", CASES)
def test_derived_quantities_are_the_runs_own_figures(results, name):
    cr = results[name]
    assert cr.case.derived
    for d in cr.case.derived:
        a, b = (cr.results[r].summary[d.metric] if d.metric in ("fps", "frame_time_ms", "latency_ms")
                else cr.columns[r][d.metric] for r in d.runs)
        want = a / b if d.kind == "ratio" else a - b
        assert cr.derived[d.name] == pytest.approx(want, rel=1e-12)


def test_gain_is_the_fps_ratio_and_more_gpus_help(results):
    cr = results["vulkan_thesis"]
    fps = {r: cr.results[r].summary["fps"] for r in ("sf_1gpu", "sf_2gpu", "sf_3gpu")}
    assert cr.derived["sf_gain_2"] == pytest.approx(fps["sf_2gpu"] / fps["sf_1gpu"])
    assert 1.5 < cr.derived["sf_gain_2"] < cr.derived["sf_gain_3"] <= 3.0
    # the reference code's loop (a barrier per frame) never beats full pipelining
    for n in (2, 3):
        assert cr.derived[f"sf_gain_{n}_as_built"] < cr.derived[f"sf_gain_{n}"]
        assert cr.derived[f"sl_gain_{n}_as_built"] < cr.derived[f"sl_gain_{n}"]


def test_span_column_matches_the_trace(results):
    cr = results["xr_stereo"]
    exp, res = cr.experiments["quest3_pcie4_weak"], cr.results["quest3_pcie4_weak"]
    rows = steady(res.trace, exp)
    p2p = rows[rows["step"] == "p2p"]
    assert len(p2p) == rows["frame"].nunique()  # one view crosses per frame with 2 GPUs
    want = ((p2p["end_ns"] - p2p["start_ns"]).mean()) / 1e6
    assert cr.columns["quest3_pcie4_weak"]["transfer_ms"] == pytest.approx(want)
    # 2064 x 2208 x 8 B over the sample's 25 GiB/s: about 1.36 ms
    assert want == pytest.approx(2064 * 2208 * 8 / 26.84e9 * 1e3, rel=0.01)


def test_copy_limited_fps_is_the_busiest_copy_queue(results):
    cr = results["dx12_pipelining"]
    exp, res = cr.experiments["linked"], cr.results["linked"]
    rows = steady(res.trace, exp)
    copies = rows[rows["step"] == "p2p"]
    per_frame_ns = (copies["end_ns"] - copies["start_ns"]).sum() / rows["frame"].nunique()
    assert cr.columns["linked"]["copy_fps"] == pytest.approx(1e9 / per_frame_ns)
    # the copies move 91.6 MB per frame over 6.7 GB/s: copy-bound near 73 fps, GPU 1 bound at 69
    assert 70 < cr.columns["linked"]["copy_fps"] < 76
    assert copy_limited_fps(rows, "no_such_step") == math.inf
    assert span_ms(rows, "no_such_step") == 0.0


def test_sections_fit_is_the_memory_model(results):
    """Sort-last gives each GPU 12/N whole sections; a GPU loads as many as fit beside its
    render targets (at most colour + depth + a final colour: 10 B per pixel), each whole."""
    cr = results["vulkan_thesis"]
    counts = []
    for n in (1, 2, 3):
        exp = cr.experiments[f"terrain_{n}"]
        section = exp.scene.sections[0].bytes
        pixels = exp.scene.width * exp.scene.height
        per_gpu = [min(12 // n, (exp.profile.gpus[gpu].memory_bytes - pixels * 10) // section) for gpu in range(n)]
        counts.append(cr.columns[f"terrain_{n}"]["sections"])
        assert counts[-1] <= sum(per_gpu)
    assert counts == sorted(counts) and counts[0] < counts[2]  # sort-last holds more on more GPUs
    assert "terrain_1" not in cr.results  # the whole terrain overflows one GPU: memory only
    assert "sections" not in cr.columns["sf_1gpu"]


def test_sections_fit_needs_sections(results):
    exp = results["vulkan_thesis"].experiments["sf_1gpu"]
    with pytest.raises(InputError, match="scene.sections"):
        sections_rendered(exp)


def test_particle_new_wait_ticks_slower_than_frames_when_the_copy_is_long(results):
    cr = results["particle_offload"]
    big = cr.columns["two_gpus_new_wait_65536"]  # the round trip (~20 ms) outlasts two frames
    assert big["update_hz"] < cr.results["two_gpus_new_wait_65536"].summary["fps"] / 2
    assert big["movement_ms"] > big["particle_ms"] > 0
    assert cr.derived["wait_cost_1m"] > 0


def test_run_case_is_deterministic():
    case = load_case("xr_stereo")
    a, b = run_case(case, frames=8), run_case(case, frames=8)
    assert a.derived == b.derived
    assert table(a).equals(table(b))


def test_unknown_case_is_one_clear_error():
    with pytest.raises(InputError, match="did you mean 'vulkan_thesis'.*the cases are: dx12_pipelining"):
        load_case("vulkan_thesi")


def test_cli_lists_runs_and_writes(tmp_path, capsys):
    assert cli.main(["case", "--list"]) == 0
    listed = capsys.readouterr().out
    assert all(name in listed for name in CASES)
    assert cli.main(["case", "nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no case of that name" in err
    out = tmp_path / "xr"
    assert cli.main(["case", "xr_stereo", "--out", str(out), "--frames", "8"]) == 0
    text = (out / "predictions.md").read_text()
    assert "weak" in text and "strong" in text
    drawn = {p.name for p in out.glob("timeline_*.png")}
    assert drawn == {f"timeline_{n}.png" for n in load_case("xr_stereo").timelines}
    assert cli.main(["case", "xr_stereo", "--frames", "1"]) == 2


def _case_file(tmp_path: Path, body: str, top: str = "") -> Path:
    """A one-run case file: `top` goes before the run (top-level keys), `body` after it."""
    exp = (ROOT / "experiments" / "cases" / "xr_stereo" / "quest3_pcie4.toml").as_posix()
    path = tmp_path / "case.toml"
    path.write_text(f'name = "t"\ntitle = "t"\n{top}[[runs]]\nname = "a"\nlabel = "a"\nexperiment = "{exp}"\n' + body)
    return path


@pytest.mark.parametrize("top, body, field", [
    ('', '[[derived]]\nname = "g"\nlabel = "g"\nkind = "ratio"\nmetric = "fps"\nruns = ["a", "b"]\n', "derived.runs"),
    ('', '[[derived]]\nname = "g"\nlabel = "g"\nkind = "ratio"\nmetric = "fsp"\nruns = ["a", "a"]\n', "derived.metric"),
    ('', '[[columns]]\nname = "c"\nlabel = "c"\nkind = "utilisation"\nselect = "gpu*"\n', "columns.kind"),
    ('', '[[columns]]\nname = "c"\nlabel = "c"\nkind = "span"\n', "columns.select"),
    ('', 'simulate = false\n[[columns]]\nname = "c"\nlabel = "c"\nkind = "span"\nselect = "x"\nruns = ["a"]\n',
     "columns.runs"),
    ('', 'simulate = false\n[[derived]]\nname = "g"\nlabel = "g"\nkind = "ratio"\nmetric = "fps"\nruns = ["a", "a"]\n',
     "derived.runs"),
    ('timelines = ["a"]\n', 'simulate = false\n', "timelines"),
    ('timelines = ["b"]\n', '', "timelines"),
    ('', '[[runs]]\nname = "a"\nlabel = "again"\nexperiment = "x.toml"\n', "runs.experiment"),
    ('colums = 1\n', '', "colums"),
    ('', 'each = { "schedule.gpus" = [1], "scene.width" = [64] }\n', "runs.each"),
    ('', 'each = { "schedule.gpus" = [] }\n', "runs.each.schedule.gpus"),
    ('', '[[columns]]\nname = "c"\nlabel = "c"\nkind = "span"\nselect = "x"\n' * 2, "columns"),
])
def test_bad_case_files_name_the_field(tmp_path, top, body, field):
    with pytest.raises(InputError) as exc:
        load_case(_case_file(tmp_path, body, top))
    assert re.sub(r"\[\d+\]", "", exc.value.field or "") == field


def test_a_bad_override_names_the_run(tmp_path):
    path = _case_file(tmp_path, 'set = ["schedule.gpus=9"]\n')
    with pytest.raises(InputError, match=r"schedule.gpus.*run 'a' of .*case.toml"):
        run_case(load_case(path), frames=4)


def test_sections_table_adds_equal_sections(tmp_path):
    path = _case_file(tmp_path, 'simulate = false\nsections = { count = 3, geometry_bytes = 5, texture_bytes = 7 }\n')
    exp = load_case(path).runs[0].load()
    assert [(s.name, s.bytes) for s in exp.scene.sections] == [(f"section_{i:02d}", 12) for i in range(3)]


def test_each_expands_one_run_per_value(tmp_path):
    path = _case_file(tmp_path, "")
    text = path.read_text().replace('label = "a"\n', 'label = "a"\neach = { "schedule.gpus" = [1, 2] }\n')
    path.write_text(text)
    case = load_case(path)
    assert [r.name for r in case.runs] == ["a_1", "a_2"]
    assert case.runs[1].sets[-1] == "schedule.gpus=2"


@pytest.mark.parametrize("name", CASES)
def test_lavapipe_study_loads_and_simulates_on_the_lavapipe_profile(name):
    """The lead measures these on lavapipe; here: they load, their sweeps are the measure
    library's, and every configuration simulates on the committed lavapipe profile."""
    study = load_study(ROOT / "experiments" / "cases" / name / "lavapipe.toml")
    assert study.calibration and study.held_out
    try:
        from mgpusim.measure.microbench import parse_sweeps
    except ImportError:  # pragma: no cover - the Vulkan extra is not installed
        parse_sweeps = None
    if parse_sweeps is not None:
        for kind, sweep in study.microbenchmarks.sweeps:
            parse_sweeps(kind, [f"{k}=" + ",".join(map(str, v)) for k, v in sweep.items()])
    for kind, sweep in study.microbenchmarks.sweeps:  # where a mesh draws: a valid placement
        for place in (sweep.get("place", ()) if kind == "mesh" else ()):
            for w, h in zip(sweep["width"], sweep["height"]):
                mesh_placement({"width": w, "height": h, "place": place})
    for entry in study.entries():
        exp = entry.load(study.profile, ["schedule.frames=6", "schedule.warmup_frames=2"])
        assert exp.scene.width * exp.scene.height <= 256 * 256
        assert simulate(exp).summary["frame_time_ms"] > 0


def test_case_type_is_what_load_case_returns():
    assert isinstance(load_case(ROOT / "experiments" / "cases" / "vulkan_thesis"), Case)
    assert metric(run_case(load_case("xr_stereo"), frames=6), "quest3_pcie4_one", "gather_ms") > 0


@pytest.mark.parametrize("name", CASES)
def test_docs_page_shows_the_current_predictions(name):
    """The page's table is what the command prints now (refresh: docs/cases/refresh.py)."""
    page = (ROOT / "docs" / "cases" / f"{name}.md").read_text()
    cr = run_case(load_case(name))
    stale = f"docs/cases/{name}.md is out of date: run PYTHONPATH=. python docs/cases/refresh.py"
    assert docs_block(page) == markdown(cr), stale
    if cr.case.published:
        assert docs_block(page, COMPARISON) == comparison_markdown(cr), stale
    for run in load_case(name).timelines:
        assert (ROOT / "docs" / "img" / "cases" / f"{name}_{run}.png").is_file()
        assert f"../img/cases/{name}_{run}.png" in page


def test_docs_block_round_trip():
    page = "intro\n<!-- predictions:start -->\nold\n<!-- predictions:end -->\nafter\n"
    new = with_docs_block(page, "| a |\n")
    assert docs_block(new) == "| a |\n"
    assert new.startswith("intro\n") and new.endswith("after\n")
    assert docs_block("no markers") == ""


def test_comparison_csv_and_the_figures_each_set_at_most_one_parameter(tmp_path, capsys):
    out = tmp_path / "dx12"
    assert cli.main(["case", "dx12_pipelining", "--out", str(out), "--frames", "12"]) == 0
    printed = capsys.readouterr().out
    assert "Compared with the published figures" in printed and "1.7x" in printed
    df = pd.read_csv(out / "comparison.csv")
    assert list(df.columns) == ["quantity", "published", "predicted", "error"]
    assert df.loc[0, "quantity"] == "gain" and df.loc[0, "published"] == 1.7
    assert df.loc[0, "error"] == pytest.approx(df.loc[0, "predicted"] / 1.7 - 1)
    for name in CASES:
        case = load_case(name)
        sets = [p.sets for p in case.published if p.sets]
        assert len(sets) == len(set(sets)) and set(sets) <= {p.name for p in case.parameters}


def test_comparison_is_each_figure_beside_its_prediction(results):
    cr = results["vulkan_thesis"]
    df = comparison(cr).set_index("quantity")
    assert df.loc["sf_gain_2", "predicted"] == cr.derived["sf_gain_2_as_built"]
    assert "sf_util_2" not in df.index  # gain / N in the thesis: it would be met by construction
    assert df.loc["terrain_sections", "predicted"] == 3  # one GTX 1080 holds 3 of the 12 sections


def test_parameters_apply_to_the_runs_they_name():
    case = load_case("vulkan_thesis")
    tc1 = case.run("sl_2gpu_as_built").load(parameter_overrides(case, "sl_2gpu_as_built"))
    assert tc1.profile.gpus[1].copy["transfer"].caps_gbps["d2h"] == case.parameter("copy_engine_gbps").value
    assert tc1.profile.host.dispatch_ns == case.parameter("handoff_ns").value
    assert "profile.gpus.1.costs.mesh.ns_per_triangle" not in parameter_overrides(case, "sl_2gpu_as_built")
    terrain = case.run("terrain_1").load(parameter_overrides(case, "terrain_1"))
    assert terrain.scene.sections[0].texture_bytes == round(358333333.0 * 6.667)


def test_calibrate_finds_the_value_the_figure_sets():
    """The DX12 talk's 1.7x sets the primary pass: the search lands on the case file's value."""
    case = load_case("dx12_pipelining")
    found = calibrate(case, frames=12, rounds=1)
    assert found["primary_ms"] == pytest.approx(case.parameter("primary_ms").value, rel=0.01)


@pytest.mark.parametrize("extra, field", [
    ('[[parameters]]\nname = "p"\nlabel = "p"\nsource = "s"\nvalue = 1.0\nkeys = {}\n', "parameters.keys"),
    ('[[parameters]]\nname = "p"\nlabel = "p"\nsource = "s"\nvalue = 1.0\nkeys = { "scene.width" = 1.0 }\n'
     'runs = ["zz*"]\n', "parameters.runs"),
    ('[[parameters]]\nname = "p"\nlabel = "p"\nsource = "s"\nvalue = 1.0\nkeys = { "scene.width" = 1.0 }\n'
     'bounds = [2, 1]\n', "parameters.bounds"),
    ('[[published]]\nname = "f"\nlabel = "f"\nvalue = 1.0\nsource = "s"\nquantity = "a:fsp"\n', "published.quantity"),
    ('[[published]]\nname = "f"\nlabel = "f"\nvalue = 1.0\nsource = "s"\nquantity = "a:fps"\nsets = "q"\n',
     "published.sets"),
    ('[[parameters]]\nname = "p"\nlabel = "p"\nsource = "s"\nvalue = 1.0\nkeys = { "scene.width" = 1.0 }\n'
     + '[[published]]\nname = "f"\nlabel = "f"\nvalue = 1.0\nsource = "s"\nquantity = "a:fps"\nsets = "p"\n'
     + '[[published]]\nname = "g"\nlabel = "g"\nvalue = 1.0\nsource = "s"\nquantity = "a:fps"\nsets = "p"\n',
     "published"),
])
def test_bad_parameters_and_figures_name_the_field(tmp_path, extra, field):
    with pytest.raises(InputError) as exc:
        load_case(_case_file(tmp_path, extra))
    assert re.sub(r"\[\d+\]", "", exc.value.field or "") == field


def test_amdahl_gain_through_the_two_gpu_point():
    assert amdahl_gain(1.5, 2) == pytest.approx(1.5)
    assert amdahl_gain(2.0, 3) == pytest.approx(3.0)  # p = 1: linear
    assert amdahl_gain(1.5, 3) == pytest.approx(1.0 / (1.0 / 3 + 2.0 / 9))  # p = 2/3
    assert amdahl_gain(0.8, 3) < 0.8  # two GPUs slower than one: three slower still


def test_each_three_gpu_gain_stands_beside_amdahl(results):
    """The thesis case's as-built and fully pipelined families (over their own 1-GPU runs) each
    have a 1 -> 2 and a 1 -> 3 GPU gain: four rows, each the derived 3-GPU gain and the line."""
    cr = results["vulkan_thesis"]
    df = extrapolation(cr).set_index("quantity")
    assert len(df) == 4 and set(df.gpus) == {3}
    row = df.loc["sort-first frame-rate gain 1 -> 3 GPUs, as built"]
    assert row.predicted == cr.derived["sf_gain_3_as_built"]
    assert row.gain_2 == cr.derived["sf_gain_2_as_built"]
    assert row.amdahl == pytest.approx(amdahl_gain(row.gain_2, 3))
    assert "Amdahl" in extrapolation_markdown(cr)


def test_weak_and_strong_over_one_single_gpu_run_are_two_families(results):
    """XR's weak and strong gains divide the same 1-GPU run: each 4-GPU gain stands beside the
    line through its own scaling's 1 -> 2 GPU gain, not the other's."""
    cr = results["xr_stereo"]
    df = extrapolation(cr).set_index("quantity")
    weak = df.loc["Quest 3, PCIe 4.0: frame-rate gain 1 -> 4 GPUs, weak"]
    strong = df.loc["Quest 3, PCIe 4.0: frame-rate gain 1 -> 4 GPUs, strong"]
    assert weak.gain_2 == cr.derived["q4_weak_gain"] and strong.gain_2 == cr.derived["q4_strong_gain"]
    assert weak.predicted == cr.derived["q4_weak_gain_4gpu"] and weak.gpus == 4
