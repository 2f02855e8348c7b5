"""Hypothesis fuzz of study files and sweep arguments: whatever a study file or a sweep's
arguments hold, the outcome is a loaded study (every name a plain file name, every path where
the file says) or a finished sweep, else one InputError / one line and exit 2; never another
exception. Bounded examples (seconds on 2 cores); no network address is ever contacted: Dask
addresses are fuzzed through the checker alone."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from mgpusim.cli import main
from mgpusim.model.errors import InputError
from mgpusim.model.toml_checks import name_problem
from mgpusim.studies.study_file import load_study
from mgpusim.sweeps import grid as sweeps
from tests.test_bad_inputs import SWEEP, mini_study


def fuzz(examples: int) -> settings:
    """Bounded, reproducible examples (FUZZ_EXAMPLES in the environment runs more)."""
    return settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", examples)), deadline=None,
                    derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                             HealthCheck.too_slow])

# ----- values a TOML file can hold ---------------------------------------------------------
NASTY_TEXT = st.sampled_from(["", " ", "..", ".", "/", "a/b", "../x", "/tmp/x", "a\\b", "a\0b", "a\nb",
                              "x" * 300, "\ufeff", "schedule.gpus=2", "schedule.gpuz=2", "=", "mesh",
                              "fragment_loop", "pixel", "present", "dispatch_ns", "host_copy.csv", "nope.csv"])
SCALARS = st.one_of(st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_infinity=True),
                    st.booleans(), NASTY_TEXT, st.text(max_size=12))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                      max_leaves=6)


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    """Every place in a nested dict/list (as a tuple of keys and indices)."""
    out = [prefix] if prefix else []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        out += _paths(v, (*prefix, k))
    return out


def _set(node: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        node = node[k]
    if value is _DELETE:
        if isinstance(node, dict):
            node.pop(path[-1], None)
        return
    node[path[-1]] = value


_DELETE = object()


@st.composite
def mutated_study(draw: st.DrawFn, tmp: Path) -> dict[str, Any]:
    """The mini study of tests/test_bad_inputs.py with one to three places replaced, deleted, or
    given an extra key."""
    data = mini_study(tmp)
    for _ in range(draw(st.integers(1, 3))):
        places = _paths(data)
        path = draw(st.sampled_from(places))
        action = draw(st.sampled_from(["value", "value", "delete", "extra"]))
        if action == "extra":
            target = data
            for k in path:
                target = target[k]
            if isinstance(target, dict):
                target[draw(st.text(min_size=1, max_size=8))] = draw(VALUES)
            continue
        _set(data, path, _DELETE if action == "delete" else draw(VALUES))
    return data


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz_study")


@fuzz(80)
@given(data=st.data())
def test_a_fuzzed_study_file_loads_whole_or_is_one_input_error(study_dir: Path, data: st.DataObject):
    study = data.draw(mutated_study(study_dir))
    path = study_dir / "s.toml"
    try:
        path.write_text(tomli_w.dumps(study))
    except (TypeError, ValueError):  # not TOML (a mixed-type array in an older writer, ...)
        return
    try:
        loaded = load_study(path)
    except InputError as exc:
        assert str(exc).startswith(str(path)) and "Traceback" not in str(exc)
        event("refused")
        return
    event("loaded")
    for entry in loaded.entries():  # what loads is safe to use as folders and files
        assert name_problem(entry.name) is None
        assert entry.experiment.is_file() and str(entry.experiment).startswith(str(study_dir))  # relative to it
    assert name_problem(loaded.name) is None
    mb = loaded.microbenchmarks
    if mb.folder is not None:
        assert all((mb.folder / f).is_file() and ".." not in Path(f).parts for f in mb.files)
    for _name, sweep in (*mb.sweeps, *mb.pairs):
        assert all(values and all(isinstance(v, (int, float, str, bool)) for v in values)
                   for values in sweep.values())
    for values in loaded.recipe.host_grid.values():
        assert values and all(isinstance(v, (int, float)) and math.isfinite(v) for v in values)


# ----- sweep arguments ---------------------------------------------------------------------
GOOD_KEYS = {"schedule.gpus": ["1", "2", "3"], "scene.width": ["64", "1024", "1920"],
             "schedule.frames": ["20", "40"], "scene.passes.0.iterations": ["100", "1000.5"],
             "profile.gpus.0.speed": ["0.5", "2"], "schedule.host_copy": ["true", "false"]}
BAD_KEYS = st.one_of(st.sampled_from(["point", "error", "wall_s", "fps", "utilization.gpu0.graphics",
                                      "schedule.gpuz", "name", "a..b", "", " ", "schedule.warmup_frames"]),
                     st.text(max_size=10).filter(lambda t: "\0" not in t))
BAD_VALUES = st.one_of(st.sampled_from(["0", "-1", "nan", "inf", '"x"', "[1]", "{a=1}", "1e400", "", " "]),
                       st.integers(-5, 3000).map(str), st.text(max_size=6).filter(lambda t: "\0" not in t))


@st.composite
def grid_item(draw: st.DrawFn) -> tuple[str, list[str]]:
    """A grid key and its values: mostly a real key with real values, sometimes anything."""
    if draw(st.integers(0, 3)):
        key = draw(st.sampled_from(sorted(GOOD_KEYS)))
        values = draw(st.lists(st.sampled_from(GOOD_KEYS[key]), min_size=1, max_size=3, unique=True))
        if draw(st.integers(0, 4)) == 0:
            values.append(draw(BAD_VALUES))
        return key, values
    return draw(BAD_KEYS), draw(st.lists(BAD_VALUES, max_size=3))


METRICS = st.one_of(st.sampled_from(["frame_time_ms", "fps", "wall_s", "latency_ms"]),
                    st.sampled_from(["fidelity", "frame_tme_ms", "utilization.gpu0.graphics", "utilization",
                                     "modelled_effects.0", "", "point"]),
                    st.text(max_size=12).filter(lambda t: "\0" not in t))


def _fake_point(experiment: str, overrides: Any, options: Any) -> dict[str, Any]:
    """A point's record without simulating it: the fuzz is about the arguments."""
    return {"summary": {"frame_time_ms": 1.0, "fps": 1000.0, "latency_ms": 2.0}, "error": None, "wall_s": 0.0}


@pytest.mark.filterwarnings("ignore:Glyph:UserWarning")  # a fuzzed value in a plot label
@fuzz(60)
@given(grid=st.lists(grid_item(), min_size=0, max_size=3), metric=METRICS,
       workers=st.one_of(st.none(), st.none(), st.integers(-2, 400)),
       sets=st.lists(st.one_of(grid_item().map(lambda kv: (kv[0], (kv[1] or [""])[0]))), max_size=2))
def test_fuzzed_sweep_arguments_run_or_are_one_line(tmp_path_factory, monkeypatch, capsys, grid, metric,
                                                    workers, sets):
    monkeypatch.setattr(sweeps, "run_point", _fake_point)
    out = tmp_path_factory.mktemp("fuzz_sweep") / "out"
    argv = ["sweep", SWEEP, "--no-progress", "--out", str(out), "--metric", metric]
    argv += [a for key, values in grid for a in ("--grid", f"{key}={','.join(values)}")]
    argv += [a for key, value in sets for a in ("--set", f"{key}={value}")]
    refused_workers = workers is not None and not 1 <= workers <= 256
    argv.append(f"--workers={workers if refused_workers else 1}")  # valid counts run here, not forked
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: one line too
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    event(f"exit {code}")
    if code == 0:
        assert (out / "sweep.parquet").is_file()
        return
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    if refused_workers:
        assert not out.exists()  # refused before any folder


@fuzz(200)
@given(address=st.one_of(st.text(max_size=40),
                         st.builds(lambda s, h, p: f"{s}{h}:{p}", st.sampled_from(["", "tcp://", "tls://", "http://",
                                                                                   "inproc://", "ucx://"]),
                                   st.sampled_from(["127.0.0.1", "localhost", "[::1]", "", "host name", "a/b"]),
                                   st.one_of(st.integers(-5, 70000).map(str), st.text(max_size=5)))))
def test_a_fuzzed_dask_address_is_accepted_only_in_its_form(address: str):
    """Checked, never contacted: an accepted address is [scheme://]host:port with a port in
    1..65535 (or a scheduler of this process, inproc://)."""
    try:
        sweeps.check_dask_address(address)
    except InputError as exc:
        assert exc.field == "--dask"
        return
    if address.startswith("inproc://"):
        return
    port = address.rsplit(":", 1)[1]
    assert port.isdigit() and 1 <= int(port) <= 65535 and " " not in address and "/" not in address.split("://")[-1]
