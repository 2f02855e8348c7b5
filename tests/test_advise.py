"""`mgpusim advise`: the options it searches, the bound that proves its best, the report it
writes, and that report opened in a real headless browser (Chromium, where installed)."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_experiment
from mgpusim.advise.advisor import CHUNKS, LINKS, options, pareto, search
from mgpusim.advise.report import write_advice
from mgpusim.cli import main
from tests.headless_browser import NO_BROWSER, find_browser, open_page

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "frames"
PROFILE = ROOT / "hardware_profiles" / "pcie4_pair.toml"


@pytest.fixture(scope="module")
def frame(tmp_path_factory) -> Path:
    """A five-pass frame on GTX-class GPUs: geometry-bound shadows, pixel-bound rest."""
    tmp = tmp_path_factory.mktemp("frame")
    csv = tmp / "f.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n"
                   "shadow,graphics,1.5,,shadowmap,4194304,0\n"
                   "gbuffer,graphics,3.0,,gb,16588800,0.6\n"
                   "light,graphics,2.0,gb;shadowmap,hdr,16588800,1\n"
                   "taa,graphics,0.6,hdr;out,out,8294400,1\n"
                   "post,graphics,0.8,out,ldr,8294400,1\n")
    out = tmp / "f.toml"
    assert main(["frame", "import", str(csv), "--size", "1920x1080", "--profile", str(PROFILE),
                 "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def advice(frame):
    return search(frame, max_gpus=3, links=LINKS[1::3], workers=1)


def test_every_option_is_there(frame):
    exp = load_experiment(frame)
    opts = options(exp, max_gpus=3, links=LINKS)
    pcie = [link for link in LINKS if not link.nvlink]
    families = pd.Series([o.family for o in opts]).value_counts().to_dict()
    assert families["one GPU"] == 1
    assert families["sort-first balanced"] == families["sort-last"] == 2 * len(pcie) * 2  # 2-3 GPUs, 2 stagings
    assert families["AFR"] == 2 * len(LINKS)
    assert families["pipelining"] == len(exp.scene.passes) * len(CHUNKS) * len(LINKS)
    assert "XR" not in families  # one view
    afr = next(o for o in opts if o.family == "AFR" and o.gpus == 3)
    assert afr.overrides["schedule"]["temporal_pass"] == "taa"  # reads its own last output
    assert afr.overrides["schedule"]["frames_in_flight"] == 3


def test_a_two_view_frame_adds_xr_and_both_eyes_elsewhere(tmp_path):
    out = tmp_path / "xr.toml"
    assert main(["frame", "import", str(EXAMPLES / "xr_two_views_lavapipe.csv"), "--size", "192x192",
                 "--profile", str(PROFILE), "--out", str(out)]) == 0
    opts = options(load_experiment(out), max_gpus=4, links=LINKS[:1])
    xr = [o for o in opts if o.family == "XR"]
    assert sorted((o.gpus, o.settings) for o in xr) == [(2, "strong scaling"), (2, "weak scaling"),
                                                         (4, "strong scaling"), (4, "weak scaling")]
    afr = next(o for o in opts if o.family == "AFR")
    assert [p["name"] for p in afr.overrides["scene.passes"]] == ["tori.left", "tori.right"]


def test_the_search_confirms_its_best_and_the_bound_proves_it(advice):
    table = advice.table
    assert advice.counts["failed"] == 0 and advice.analytic_bound and advice.open == 0
    done = table[table["confirmed"]]
    # the analytic level is an optimistic bound on this profile: full fidelity is never faster
    assert (done["frame_time_ms"] >= done["fast_frame_time_ms"] - 1e-9).all()
    best = advice.ranked.iloc[0]
    assert best["frame_time_ms"] == done["frame_time_ms"].min()
    unconfirmed = table[~table["confirmed"]]
    assert (unconfirmed["fast_frame_time_ms"] >= best["frame_time_ms"]).all()
    assert table.loc[0, "speedup"] == 1.0 and best["speedup"] > 1.5
    assert set(done["gpus"]) == {1, 2, 3}  # the best of each GPU count is confirmed
    assert set(done["family"]) == set(table["family"])  # and of each schedule


def test_the_pareto_front_holds_no_beaten_option():
    df = pd.DataFrame({"t": [1.0, 2.0, 2.0, 3.0, 1.005, 0.999], "l": [5.0, 2.0, 3.0, 1.0, 5.0, 5.01]})
    # 2 is beaten by 1; 4 by 0; 0 and 5 beat each other within 1 %: the faster one stays
    assert pareto(df, ["t", "l"]) == [1, 3, 5]


def test_the_report_folder(advice, tmp_path):
    files = write_advice(advice, tmp_path, "f.toml", timelines=2)
    answer = json.loads(files["answer"].read_text())
    assert answer["best"]["label"] == advice.ranked.iloc[0]["label"]
    assert answer["open"] == 0 and len(answer["timelines"]) == 3  # the baseline and two
    for item in answer["timelines"]:
        assert (tmp_path / item["timeline"]).is_file() and (tmp_path / item["perfetto"]).is_file()
    table = pd.read_csv(files["table"])
    assert len(table) == advice.counts["options"]
    assert table["command"].str.startswith("mgpusim simulate f.toml --set 'schedule={").all()
    html = files["report"].read_text()
    assert "<script" not in html and "pareto.png" in html and "Pareto front" in html


@pytest.mark.skipif(find_browser() is None, reason=NO_BROWSER)
def test_the_report_renders_in_a_headless_browser(advice, tmp_path):
    files = write_advice(advice, tmp_path, "f.toml", timelines=1)
    page = open_page(files["report"], find_browser())
    assert page.title.startswith("mgpusim advise")
    assert page.errors == []
    assert len(page.images) == 3  # Pareto plot, the baseline's and the best option's timelines
    assert all(complete and width > 100 for _, complete, width in page.images), page.images
    assert all((tmp_path / href).is_file() for href in page.links), page.links


@pytest.mark.skipif(find_browser() is None, reason=NO_BROWSER)
def test_the_browser_check_sees_a_broken_page(tmp_path):
    """The positive control: a missing picture and a script error are caught."""
    page = tmp_path / "bad.html"
    page.write_text("<!DOCTYPE html><html><head><title>bad</title></head><body>"
                    "<img src=\"missing.png\"><script>console.error('boom')</script></body></html>")
    seen = open_page(page, find_browser())
    assert seen.images == [("missing.png", True, 0)]
    assert any("boom" in e for e in seen.errors)
    assert any("missing.png" in e or "ERR_FILE_NOT_FOUND" in e for e in seen.errors)


def test_advise_refuses_a_multi_gpu_experiment_in_one_line(tmp_path, capsys):
    code = main(["advise", str(ROOT / "experiments/sort_first_tc1.toml"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "schedule.gpus" in err[0]
    assert not (tmp_path / "o").exists()
