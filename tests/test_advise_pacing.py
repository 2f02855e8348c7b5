"""`mgpusim advise` ranks by frame pacing: the intervals between presents, a frame whose best
option by mean frame time stutters ranked below an evenly paced one, ties collapsed with the
cheaper link first, and a report that names only its columns."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest

from mgpusim import load_experiment, simulate
from mgpusim.advise.advisor import LINKS, PACED, RANK_MEASURE, TIE, intervals, ranking, search
from mgpusim.advise.report import HEADERS, write_advice
from mgpusim.cli import main

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "hardware_profiles" / "pcie4_pair.toml"
#: Two links of one nominal rate (PCIe 4.0 x16 = 5.0 x8) and NVLink: options over the first two tie.
TWO_EQUAL = [link for link in LINKS if link.name in ("PCIe 4.0 x16", "PCIe 5.0 x8", "NVLink 4 450 GB/s")]


# ----- the intervals between presents ----------------------------------------------------------
def test_intervals_are_the_steady_presents_percentile_and_worst():
    frames = pd.DataFrame({"frame": range(6), "present_ns": [0, 10_000_000, 11_000_000, 12_000_000,
                                                             22_000_000, 23_000_000]})
    got = intervals(frames, {"warmup_frames": 1, "frame_time_ms": 3.25})
    assert got["interval_max_ms"] == 10.0
    assert got["interval_p99_ms"] == pytest.approx(1.0 + 0.97 * 9.0)  # numpy's linear interpolation
    assert intervals(frames.head(2), {"warmup_frames": 1, "frame_time_ms": 10.0}) == {
        "interval_p99_ms": 10.0, "interval_max_ms": 10.0}


# ----- the search ranks by pacing -------------------------------------------------------------
@pytest.fixture(scope="module")
def stutter(tmp_path_factory) -> Path:
    """A frame whose TAA reads its previous output: AFR on four GPUs over NVLink has the best
    mean frame time, but its GPUs finish their frames close together and present in bursts."""
    tmp = tmp_path_factory.mktemp("stutter")
    csv = tmp / "stutter.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n"
                   "scene,graphics,4.0,,hdr,16588800,0.5\n"
                   "taa,graphics,0.5,hdr;taa,taa,8294400,1\n")
    assert main(["frame", "import", str(csv), "--size", "1920x1080", "--profile", str(PROFILE),
                 "--out", str(tmp)]) == 0
    return tmp / "stutter.toml"


@pytest.fixture(scope="module")
def paced_advice(stutter):
    return search(stutter, max_gpus=4, links=TWO_EQUAL, workers=1)


def test_the_best_by_mean_stutters_and_ranks_below_its_even_paced_self(paced_advice):
    ranked = paced_advice.ranked
    by_mean = ranked.sort_values(["frame_time_ms", "order"], kind="stable").iloc[0]
    assert by_mean["family"] == "AFR" and by_mean["gpus"] == 4 and by_mean["link"] == "NVLink 4 450 GB/s"
    assert by_mean["interval_p99_ms"] > 2 * by_mean["frame_time_ms"]  # bursts, then a wait
    even = ranked[ranked["paced_from"] == by_mean.name].iloc[0]
    assert even["family"] == PACED
    assert even["interval_p99_ms"] == pytest.approx(even["frame_time_ms"], rel=1e-6)  # every interval alike
    assert even["interval_max_ms"] == pytest.approx(even["frame_time_ms"], rel=1e-6)
    assert even["frame_time_ms"] <= by_mean["frame_time_ms"] * 1.05  # at nearly the same mean
    assert even["rank"] < by_mean["rank"]
    assert ranked.iloc[0]["family"] == PACED
    # the paced option's command reproduces it
    over = paced_advice.overrides(int(even.name))
    assert over["schedule"]["pace_us"] * 1000 >= by_mean["frame_time_ms"] * 1e6 - 1
    got = simulate(load_experiment(paced_advice.experiment, over), record_trace=False)
    assert got.summary["frame_time_ms"] == pytest.approx(even["frame_time_ms"])


def test_the_bound_still_proves_the_best_by_the_measure(paced_advice):
    table = paced_advice.table
    done = table[table["confirmed"]]
    assert paced_advice.analytic_bound and paced_advice.open == 0
    assert (done["frame_time_ms"] >= done["fast_frame_time_ms"] - 1e-9).all()
    assert (done["rank_ms"] >= done["frame_time_ms"]).all()  # the measure is never below the mean
    best = paced_advice.ranked.iloc[0]["rank_ms"]
    assert (table.loc[~table["confirmed"] & table["error"].isna(), "fast_frame_time_ms"] >= best).all()


def test_ties_collapse_with_the_cheaper_link_first(paced_advice):
    rows = paced_advice.ranked
    tied = rows[rows["also_on"].fillna("") != ""]
    assert len(tied)  # every schedule on PCIe 4.0 x16 ties with itself on PCIe 5.0 x8
    assert set(tied["link"]) == {"PCIe 4.0 x16"} and set(tied["also_on"]) == {"PCIe 5.0 x8"}
    for _, head in tied.iterrows():
        twin = rows[(rows["rank"] == head["rank"]) & (rows.index != head.name)]
        assert list(twin["link"]) == ["PCIe 5.0 x8"] and twin["order"].iloc[0] > head["order"]
    one_row = rows.drop_duplicates("rank")
    assert not one_row.duplicated(["family", "gpus", "settings", "rank_ms", "latency_ms"]).any()
    # a row is on the Pareto front when one of its options is: the cheapest stands for it
    assert (rows.groupby("rank")["pareto"].nunique() == 1).all() and one_row["pareto"].any()


def test_ranking_orders_a_tie_by_latency_then_gpus_then_the_cheaper_link():
    links = {name: k for k, name in enumerate(["cheap", "mid", "dear"])}
    ok = pd.DataFrame({
        "family": ["A", "A", "A", "B", "B", "C"], "gpus": [4, 4, 4, 2, 4, 2],
        "settings": ["", "", "", "", "", ""], "link": ["dear", "cheap", "mid", "dear", "cheap", "cheap"],
        "rank_ms": [1.000, 1.000, 1.004, 1.005, 1.009, 1.02],
        "latency_ms": [5.0, 5.0, 5.0, 5.02, 3.0, 1.0]}, index=[10, 11, 12, 13, 14, 15])
    got = ranking(ok, links, TIE)
    # 10-14 tie on the measure (within 1 % of 1.000), 15 does not; in the tie the lower
    # latency first (14), then 10-13 (latencies within 1 %): 2 GPUs before 4, then cheap,
    # mid, dear; A x4 on three links is one row under the cheap one
    assert list(got.index) == [14, 13, 11, 12, 10, 15]
    assert list(got["rank"]) == [1, 2, 3, 3, 3, 4]
    assert got.loc[11, "also_on"] == "mid, dear"
    assert pd.isna(got.loc[12, "also_on"]) and got.loc[12, "stands_for"] == 11


def test_the_report_states_the_measure_and_names_only_its_columns(paced_advice, tmp_path):
    files = write_advice(paced_advice, tmp_path, "stutter.toml", timelines=1)
    html = files["report"].read_text()
    assert RANK_MEASURE in html and "By mean frame time alone the best would be" in html
    assert "_lo/_hi" not in html and "_lo" not in html
    # every column a caption quotes is a header of one of the page's tables
    headers = set(re.findall(r"<th[^>]*>([^<]*)</th>", html))
    for caption in re.findall(r"<p[^>]*>(.*?)</p>", html, flags=re.S):
        for quoted in re.findall(r"&quot;([^&]*)&quot;", caption):
            if quoted in HEADERS.values():
                assert quoted in headers, quoted
    assert HEADERS["interval_p99_ms"] in headers and HEADERS["interval_max_ms"] in headers
    answer = json.loads(files["answer"].read_text())
    assert answer["ranked_by"] == RANK_MEASURE and answer["tie_share"] == TIE
    assert answer["best"]["family"] == PACED and answer["best_by_mean"]["family"] == "AFR"
    table = pd.read_csv(files["table"])
    assert {"interval_p99_ms", "interval_max_ms", "rank_ms", "also_on", "paced_from"} <= set(table.columns)


def test_a_band_caption_only_where_the_band_is(paced_advice, tmp_path):
    table = paced_advice.table
    has_band = "frame_time_ms_lo" in table and table["frame_time_ms_lo"].notna().any()
    html = write_advice(paced_advice, tmp_path, "stutter.toml", timelines=0)["report"].read_text()
    assert (HEADERS["frame_time_ms_lo"] in html) == has_band
