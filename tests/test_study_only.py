"""`mgpusim study measure --only`: which configurations a regular expression keeps."""
from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from mgpusim.commands.study import _filtered
from mgpusim.model.errors import InputError
from mgpusim.studies.study_file import load_study

STUDY = Path(__file__).resolve().parents[1] / "experiments" / "h200" / "study.toml"


def _names(only: str) -> set[str]:
    study = _filtered(load_study(STUDY), argparse.Namespace(only=only))
    return {e.name for e in study.calibration + study.held_out}


def test_a_plain_substring_keeps_every_name_that_contains_it() -> None:
    names = _names("sf_")
    assert "cal_sf_4k_it250" in names and "sf_4k_it500" in names
    assert not any("sl_" in n for n in names)


def test_an_anchored_pattern_splits_the_calibration_runs_off() -> None:
    held_out_sf = _names("^sf_")
    assert held_out_sf and all(n.startswith("sf_") for n in held_out_sf)
    groups = ("^cal_", "^sf_", "^sl_", "^afr_", "^afrt_", "^xr_s", "^xr_w", "^pipe_", "^part_")
    kept = [_names(g) for g in groups]  # the groups the study was measured in
    assert set().union(*kept) == _names("")
    assert sum(len(k) for k in kept) == len(_names(""))  # each configuration in one group


@pytest.mark.parametrize("only, words", [("([", "not a regular expression"),
                                         ("^nothing", "matches no configuration")])
def test_a_bad_or_empty_pattern_is_one_clear_error(only: str, words: str) -> None:
    with pytest.raises(InputError, match=words):
        _names(only)
