"""Input the tool used to take silently or misread: a pass without its work, a signed
`--effects` value, sweeps whose base or keys cannot load, and sweeps where every point fails."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

import mgpusim
from mgpusim.cli import join_signed_values, main

ROOT = Path(__file__).resolve().parents[1]
SORT_FIRST = str(ROOT / "experiments" / "sort_first_tc1.toml")


def _mesh_without_triangles(tmp: Path) -> Path:
    path = tmp / "mesh.toml"
    path.write_text(f'name = "m"\nprofile = "{ROOT / "hardware_profiles" / "tc1.toml"}"\n'
                    '[scene]\nwidth = 64\nheight = 48\n[[scene.passes]]\nname = "m"\nkind = "mesh"\n'
                    '[schedule]\nname = "sort_last"\ngpus = 2\nframes = 10\nwarmup_frames = 2\n')
    return path


@pytest.mark.parametrize("kind, needed", [("mesh", "triangles"), ("fragment_loop", "iterations"),
                                          ("filter", "iterations"), ("timed", "duration_ms")])
def test_a_scene_pass_without_its_work_is_refused(tmp_path, kind, needed):
    path = _mesh_without_triangles(tmp_path)
    path.write_text(path.read_text().replace('kind = "mesh"', f'kind = "{kind}"'))
    with pytest.raises(mgpusim.InputError, match=f"passes\\[0\\].{needed}: missing: a {kind} pass needs"):
        mgpusim.load_experiment(path)


def test_effects_take_a_leading_minus_as_the_docs_write_it(tmp_path):
    assert join_signed_values(["simulate", "x", "--effects", "-task_gaps"]) == [
        "simulate", "x", "--effects=-task_gaps"]
    assert join_signed_values(["--effects", "--out", "o"]) == ["--effects", "--out", "o"]
    assert main(["simulate", SORT_FIRST, "--effects", "-task_gaps,+link_sharing",
                 "--out", str(tmp_path / "o")]) == 0
    effects = json.loads((tmp_path / "o" / "summary.json").read_text())["modelled_effects"]
    assert "link_sharing" in effects and "task_gaps" not in effects


def test_a_sweep_of_a_broken_base_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["sweep", str(_mesh_without_triangles(tmp_path)), "--grid", "schedule.gpus=1,2",
                 "--out", str(out), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs triangles" in err[0] and not out.exists()


def test_a_grid_key_no_value_of_which_loads_is_refused(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["sweep", SORT_FIRST, "--grid", "schedule.gpuz=1,2", "--out", str(out),
                 "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--grid schedule.gpuz" in err[0] and "did you mean 'gpus'" in err[0]
    assert not out.exists()
    with pytest.raises(mgpusim.InputError, match="schedule.gpuz"):
        mgpusim.sweep(SORT_FIRST, {"schedule.gpuz": [1]}, workers=1, progress=False)


def test_a_sweep_whose_points_all_fail_exits_non_zero_and_some_failing_does_not(tmp_path, capsys):
    args = ["--workers", "1", "--no-progress"]
    assert main(["sweep", SORT_FIRST, "--grid", "schedule.frames=12", "--grid", "schedule.warmup_frames=12",
                 "--out", str(tmp_path / "all"), *args]) == 1  # each key alone loads; together never
    assert "every point failed" in capsys.readouterr().err
    assert (tmp_path / "all" / "sweep.parquet").is_file()
    assert main(["sweep", SORT_FIRST, "--grid", "schedule.gpus=0,1", "--out", str(tmp_path / "some"), *args]) == 0


def test_a_utf8_byte_order_mark_is_skipped_in_toml_and_json(tmp_path):
    """Some editors write a BOM: the file reads as without it (TOML experiments, profiles,
    studies; JSON records)."""
    from mgpusim.validation.measured_check import read_json_object
    text = Path(SORT_FIRST).read_text().replace('"../hardware_profiles/', f'"{ROOT}/hardware_profiles/')
    (tmp_path / "e.toml").write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert mgpusim.load_experiment(tmp_path / "e.toml").schedule.name == "sort_first"
    (tmp_path / "s.json").write_bytes(b"\xef\xbb\xbf" + b'{"config": {}}')
    assert read_json_object(tmp_path / "s.json") == {"config": {}}


def test_numbers_on_the_command_line_are_ascii_finite_and_bounded():
    import argparse

    from mgpusim.cli import finite_number, whole_number
    assert whole_number("12") == 12 and whole_number(" -3 ") == -3 and whole_number("9" * 18) == int("9" * 18)
    assert finite_number("1e-3") == 0.001 and finite_number(".5") == 0.5 and finite_number("-2") == -2
    for bad in ("\u0661\u0662", "\uff11", "\u00b2", "9" * 19, "1.5", "0x10", "", "1_000"):
        with pytest.raises(argparse.ArgumentTypeError):
            whole_number(bad)
    for bad in ("nan", "inf", "-Infinity", "1e999", "\u0661.5", "1,5", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            finite_number(bad)
    with pytest.raises(SystemExit) as exit_:  # argparse's one line, from every command's options
        main(["case", "xr_stereo", "--frames", "\u0661\u0662", "--out", "unused"])
    assert exit_.value.code == 2
