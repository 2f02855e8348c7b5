"""Hypothesis fuzzing of the loaders: shipped experiments and profiles, mutated (odd values,
deleted and misspelt keys, broken TOML text), either load and simulate or fail with
mgpusim's own error. The mutations are scripts/fuzz_inputs.py's (its larger run is the
script itself); Hypothesis drives their random choices, so a failure shrinks to a small case.
"""
from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("fuzz_inputs", ROOT / "scripts" / "fuzz_inputs.py")
fuzz = importlib.util.module_from_spec(_spec)
sys.modules["fuzz_inputs"] = fuzz  # its dataclasses look their module up there
_spec.loader.exec_module(fuzz)


# derandomize: CI draws the same 200 examples every run, so a failure there is reproducible;
# the open-ended search over fresh seeds is scripts/fuzz_inputs.py
@settings(max_examples=200, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rng=st.randoms(use_true_random=False))
def test_mutated_shipped_files_fail_only_with_mgpusim_errors(rng: random.Random, tmp_path: Path):
    case = fuzz.make_case(rng)
    assert fuzz.run_case(case, tmp_path) in ("ok", "error")  # anything else raised: a crash


def test_the_fuzzer_reaches_both_outcomes(tmp_path: Path):
    """The mutations are neither all harmless nor all fatal: both outcomes occur, so the test
    above exercises the simulation as well as the error paths."""
    rng = random.Random(7)
    outcomes = {fuzz.run_case(fuzz.make_case(rng), tmp_path) for _ in range(200)}
    assert outcomes == {"ok", "error"}


def test_a_known_crash_class_is_an_mgpusim_error(tmp_path: Path):
    """A profile path longer than the file system allows was an OSError before (found by the
    fuzzer); it is now the experiment's error."""
    case = fuzz.Case("experiment", ROOT / "experiments" / "sort_first_tc1.toml", ["profile = 'x' * 5000"],
                     fuzz.read_toml(ROOT / "experiments" / "sort_first_tc1.toml"))
    case.data["profile"] = "x" * 5000
    assert fuzz.run_case(case, tmp_path) == "error"
