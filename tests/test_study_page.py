"""report.html of `mgpusim study validate` (mgpusim/studies/page.py), offline on a
few configurations of the committed 2x H100 study, and opened in a headless browser where
Chromium is installed."""
from __future__ import annotations

import html
import os
import re
import tomllib
from pathlib import Path

import pandas as pd
import pytest
import tomli_w

from mgpusim.cli import main
from tests.headless_browser import NO_BROWSER, find_browser, open_page

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "h100_x2" / "study.toml"
KEEP = {"calibration": ("afr_2gpu_4k_it1000", "xr_weak_quest3_t1M"), "held_out": ("afr_2gpu_1440p_it2000",)}


def _mini_study(folder: Path) -> Path:
    """The 2x H100 study with three of its configurations, its paths made relative to `folder`."""
    data = tomllib.loads(STUDY.read_text())
    here = STUDY.parent

    def rel(ref: str) -> str:
        return os.path.relpath((here / ref).resolve(), folder)
    data["profile"] = rel(data["profile"])
    data["microbenchmarks"]["tables"] = rel(data["microbenchmarks"]["tables"])
    for half, names in KEEP.items():
        data[half]["runs"] = rel(data[half]["runs"])
        data[half]["config"] = [dict(c, experiment=rel(c["experiment"]))
                                for c in data[half]["config"] if c["name"] in names]
    path = folder / "mini.toml"
    path.write_text(tomli_w.dumps(data))
    return path


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("study_page")
    out = folder / "out"
    assert main(["study", "validate", str(_mini_study(folder)), "--held-out", "--out", str(out)]) == 0
    return out


def test_the_page_shows_every_configuration_with_its_error_and_pictures(report: Path) -> None:
    page = (report / "report.html").read_text()
    assert "<script" not in page and page.startswith("<!DOCTYPE html>")
    assert '<p class="verdict" id="verdict"><strong>Verdict on the 1 held-out configuration: no target set.' in page
    for half, name in (("calibration", "Calibration runs"), ("held-out", "Held-out runs")):
        table = pd.read_csv(report / f"errors_{half}.csv")
        assert f"<h2>{name}" in page and f"errors_{half}.png" in page
        for row in table.itertuples():
            # the frame-time table's row: the configuration, its measured frame time, its error
            cells = re.search(rf"<tr>\s*<td>{row.config}</td>(.*?)</tr>", page, re.S)
            assert cells, row.config
            values = re.findall(r"<td[^>]*>([^<]*)</td>", cells.group(1))
            assert values[0] == f"{row.measured_frame_ms:.2f}"
            assert values[2] == f"{row.frame_time_error:+.1%}"
            assert f"validation/{row.config}/timelines.png" in page
            assert f"validation/{row.config}/measured.perfetto.json" in page
    refs = re.findall(r"(?:src|href)=\"([^\"]+)\"", page)
    local = [html.unescape(r) for r in refs if not r.startswith("http")]
    assert local and all((report / r).is_file() for r in local), [r for r in local if not (report / r).is_file()]
    assert {"afr", "xr"} <= set(re.findall(r"<h3>Calibration runs: (\w+)</h3>", page))


def test_the_page_is_report_md_rendered(report: Path) -> None:
    """One source: every heading of report.md is a heading of the page, in the same order."""
    text = (report / "report.md").read_text()
    page = (report / "report.html").read_text()
    md_heads = [line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")]
    page_heads = [html.unescape(h) for h in re.findall(r"<h[123]>(.*?)</h[123]>", page)]
    assert md_heads == page_heads


@pytest.mark.skipif(find_browser() is None, reason=NO_BROWSER)
def test_the_page_renders_in_a_headless_browser(report: Path) -> None:
    seen = open_page(report / "report.html", find_browser())
    assert seen.title.startswith("mgpusim study")
    assert seen.errors == []
    # two error plots, one timeline per configuration
    assert len(seen.images) == 2 + sum(len(v) for v in KEEP.values())
    assert all(complete and width > 100 for _, complete, width in seen.images), seen.images
    assert all((report / href).is_file() for href in seen.links if not href.startswith("http")), seen.links
