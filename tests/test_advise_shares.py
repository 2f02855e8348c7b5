"""`mgpusim advise` lists every pass's pixel share with where it came from (the import's record,
tests/test_frame_shares.py) and says how its answer moves with the assumed shares off by 0.25."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from mgpusim.advise.advisor import LINKS, search
from mgpusim.advise.assumptions import SHARE_DELTA, check_shares, shifted
from mgpusim.advise.report import write_advice
from mgpusim.frames.shares import INFERRED
from tests.test_frame_shares import DEFERRED, _import


# ----- advise lists them and checks the answer ------------------------------------------------
@pytest.fixture(scope="module")
def deferred(tmp_path_factory) -> Path:
    return _import(tmp_path_factory.mktemp("deferred"), DEFERRED)


@pytest.fixture(scope="module")
def advice(deferred):
    found = search(deferred, max_gpus=4, links=[link for link in LINKS if link.name == "PCIe 4.0 x16"], workers=1)
    check_shares(found)
    return found


def test_advise_lists_every_share_with_how_it_was_found(advice, tmp_path):
    checked = advice.assumptions
    assert [p["pass"] for p in checked["passes"]][:2] == ["shadow_cascades", "depth_prepass"]
    first = checked["passes"][0]
    assert first["pixel_share"] == 0.0 and first["geometry_share"] == 1.0 and first["source"] == INFERRED
    assert "shadow map" in first["why"]
    assert len(checked["assumed"]) == 7
    files = write_advice(advice, tmp_path, "deferred.toml", timelines=0)
    html = files["report"].read_text()
    assert "Assumptions: each pass&#x27;s pixel share" in html or "Assumptions: each pass's pixel share" in html
    assert "shadow_cascades" in html and "a shadow map" in html
    assert json.loads(files["answer"].read_text())["assumptions"]["delta"] == SHARE_DELTA


def test_the_answer_says_how_it_moves_with_the_shares_off_by_a_quarter(advice, tmp_path):
    shifts = advice.assumptions["shifts"]
    assert [s["delta"] for s in shifts] == [-SHARE_DELTA, SHARE_DELTA]
    # fewer pixels to split: sort-first gets slower; more: faster
    lower, higher = (s["families"]["sort-first balanced"] for s in shifts)
    assert lower["shifted_ms"] > lower["now_ms"] > higher["shifted_ms"]
    assert all(s["best"] and s["best_rank_ms"] > 0 for s in shifts)
    html = write_advice(advice, tmp_path, "deferred.toml", timelines=0)["report"].read_text()
    assert "With every assumed share 0.25 lower" in html and "With every assumed share 0.25 higher" in html


def test_shifting_clamps_and_leaves_stated_shares_alone():
    passes = [{"name": "a", "kind": "captured", "pixel_share": 0.1},
              {"name": "b", "kind": "captured", "pixel_share": 0.9},
              {"name": "c", "kind": "captured", "pixel_share": 0.5}]
    down = shifted(passes, {"a", "b"}, -0.25)
    assert [p["pixel_share"] for p in down] == [0.0, 0.65, 0.5]
    assert [p["pixel_share"] for p in shifted(passes, {"a", "b"}, 0.25)] == [0.35, 1.0, 0.5]
    assert passes[0]["pixel_share"] == 0.1  # a copy
