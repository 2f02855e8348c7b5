"""The verdict of a study (mgpusim/studies/verdict.py): the prediction's band, each level's
status against its target, and the one exit-status rule of `mgpusim main`, `study run` and
`study validate`, offline on a committed lavapipe job (its runs and per-run speed probes), and
the report page in a headless browser: the verdict first, the speed-flag column on screen."""
from __future__ import annotations

import io
import json
import os
import struct
import tomllib
import zlib
from pathlib import Path

import pandas as pd
import pytest
import tomli_w

from mgpusim.cli import main
from mgpusim.measure import run_speed
from mgpusim.model.errors import DependencyError
from mgpusim.studies import pipeline, verdict
from mgpusim.studies.study_file import Target, Targets, load_study
from tests.headless_browser import NO_BROWSER, find_browser, screenshot

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "experiments" / "lavapipe" / "study.toml"
JOB = ROOT / "data" / "lavapipe" / "main_job_2026-11-27_native"
#: two calibration configurations and two held-out ones, one of them flagged by the speed rule
#: (its probes 38 % apart: the machine's speed moved during the run)
KEEP = {"calibration": ("sf_1gpu_256x192_it2000", "afr_2gpu"),
        "held_out": ("xr_2gpu_host_copy", "afrt_3gpu")}
LOOSE = {"replay": {"median": 0.5, "worst": 0.5}, "prediction": {"median": 0.9, "worst": 0.9}}


def mini_study(folder: Path, targets: dict | None = LOOSE) -> Path:
    """The lavapipe study cut to KEEP, its paths made relative to `folder`, with `targets`."""
    data = tomllib.loads(STUDY.read_text())

    def rel(ref: str) -> str:
        return os.path.relpath((STUDY.parent / ref).resolve(), folder)
    data["profile"] = rel(data["profile"])
    for half, names in KEEP.items():
        data[half]["config"] = [dict(c, experiment=rel(c["experiment"]))
                                for c in data[half]["config"] if c["name"] in names]
    data.pop("targets", None)
    if targets is not None:
        data["targets"] = targets
    path = folder / f"mini_{len(list(folder.glob('mini_*.toml')))}.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def validate_args(study: Path, out: Path, *more: str) -> list[str]:
    return ["study", "validate", str(study), "--held-out", "--runs", str(JOB / "runs"),
            "--profile", str(JOB / "profile.toml"), "--out", str(out), *more]


# ----- the band and the statuses (pure) ------------------------------------------------------

def table(**columns: list) -> pd.DataFrame:
    n = len(next(iter(columns.values())))
    base = {"config": [f"c{i}" for i in range(n)], "frame_time_error": [0.0] * n,
            "replay_frame_time_error": [0.0] * n}
    return pd.DataFrame({**base, **columns})


def test_the_band_comes_from_the_probes_and_the_repeats():
    """hi: simulated at the slower probe (up to 1 + d longer); lo: the measured side from the
    slower end of the repeats (up to 1 + s longer)."""
    t = table(frame_time_error=[0.5, 0.5], normalized_frame_time_error=[0.02, -0.10],
              probe_disagreement=[0.10, 0.0], run_to_run_spread=[0.05, float("nan")])
    b = verdict.band(t)
    assert b["error"].tolist() == pytest.approx([0.02, -0.10])  # normalized, not raw
    assert b["hi"].tolist() == pytest.approx([1.02 * 1.10 - 1, -0.10])
    assert b["lo"].tolist() == pytest.approx([1.02 / 1.05 - 1, -0.10])  # no repeats: s = 0
    assert b["abs_lo"].tolist() == pytest.approx([0.0, 0.10])  # the first straddles 0
    assert b["abs_hi"].tolist() == pytest.approx([1.02 * 1.10 - 1, 0.10])


def test_a_run_without_probes_is_judged_on_its_raw_error():
    t = table(frame_time_error=[0.03, -0.01], run_to_run_spread=[0.0, 0.0])
    v = verdict.half_verdict(t, Targets(prediction=Target(0.05, 0.15)))
    assert v["prediction"]["errors"] == "raw" and v["prediction"]["median"] == pytest.approx(0.02)
    assert v["prediction"]["band"]["median"] == pytest.approx([0.02, 0.02])
    assert v["prediction"]["status"] == "met" and v["status"] == "met"


@pytest.mark.parametrize("disagreement, status", [(0.0, "met"), (0.04, "undecided"), (0.2, "undecided")])
def test_the_prediction_is_met_missed_or_undecided_by_its_band(disagreement, status):
    """A 3 % error is within a 5 % target; moved 4 % or 20 % its band reaches past it while
    its low end stays within: undecided, not refused."""
    t = table(frame_time_error=[0.03] * 3, normalized_frame_time_error=[0.03] * 3,
              probe_disagreement=[disagreement] * 3, run_to_run_spread=[0.0] * 3)
    v = verdict.half_verdict(t, Targets(prediction=Target(0.05, 0.15)))
    assert v["prediction"]["status"] == status
    words = verdict.prediction_words(v["prediction"])
    assert ("wider than the target" in words) == (status == "undecided")


def test_a_prediction_whose_band_lies_past_the_target_missed_it():
    t = table(frame_time_error=[0.2, 0.3], run_to_run_spread=[0.01, 0.01])
    v = verdict.half_verdict(t, Targets(prediction=Target(0.05, 0.15)))
    assert v["prediction"]["status"] == "missed" and v["status"] == "missed"


def test_the_replay_is_held_against_its_target_as_it_is():
    t = table(replay_frame_time_error=[0.005, -0.02, 0.01], run_to_run_spread=[0.3] * 3)
    assert verdict.half_verdict(t, Targets(replay=Target(0.01, 0.03)))["replay"]["status"] == "met"
    assert verdict.half_verdict(t, Targets(replay=Target(0.01, 0.015)))["replay"]["status"] == "missed"
    assert verdict.half_verdict(t, Targets())["status"] == "no target"


def test_the_exit_status_rule():
    def stats(status: str | None, half: str = verdict.HELD_OUT_TITLE) -> dict:
        return {} if status is None else {half: {"verdict": {"status": status}}}
    assert verdict.exit_status(stats("met")) == verdict.MET == 0
    assert verdict.exit_status(stats("no target")) == 0
    assert verdict.exit_status(stats("missed")) == verdict.MISSED == 1
    assert verdict.exit_status(stats("undecided")) == 1
    assert verdict.exit_status(stats(None)) == verdict.NOT_MEASURED == 3
    # only the calibration half compared: the verdict is its
    assert verdict.exit_status(stats("missed", verdict.CALIBRATION_TITLE)) == 1
    both = {**stats("met", verdict.CALIBRATION_TITLE), **stats("missed")}
    assert verdict.chosen_half(both) == verdict.HELD_OUT_TITLE and verdict.exit_status(both) == 1


def test_the_shipped_lavapipe_study_sets_both_targets():
    targets = load_study(STUDY).targets
    assert targets == Targets(replay=Target(0.01, 0.03), prediction=Target(0.05, 0.15))


@pytest.mark.parametrize("targets, words", [
    ({"replay": {"median": 0.05, "worst": 0.01}}, "worst may not be under the median"),
    ({"replay": {"median": 0.01}}, "targets.replay.worst: missing"),
    ({"predicton": {"median": 0.01, "worst": 0.02}}, "did you mean 'prediction'"),
    ({"replay": {"median": -0.01, "worst": 0.02}}, "must be >= 0"),
])
def test_a_bad_target_is_one_error_naming_the_field(tmp_path: Path, targets: dict, words: str):
    from mgpusim.model.errors import InputError
    with pytest.raises(InputError, match=words):
        load_study(mini_study(tmp_path, targets))


def test_the_halves_the_old_rule_refused_get_a_verdict():
    """The committed jobs of 2026-11-27 whose calibration half the old speed rule refused (15
    and 7 of 27 runs flagged): each now has a verdict, its median's band around its estimate."""
    history = pd.read_parquet(ROOT / "data" / "lavapipe" / "history" / "main_jobs.parquet")
    targets = load_study(STUDY).targets
    seen = {}
    for job in ("pair_A", "pair_D"):
        row = history[(history.job == f"main_job_2026-11-27_{job}") & (history.path == "errors_calibration.csv")]
        v = verdict.half_verdict(pd.read_csv(io.StringIO(row.text.iloc[0])), targets)
        p = v["prediction"]
        assert p["band"]["median"][0] <= p["median"] <= p["band"]["median"][1]
        assert p["band"]["worst"][0] <= p["worst"] <= p["band"]["worst"][1]
        seen[job] = (p["flagged_runs"], p["status"], v["replay"]["status"])
    assert seen == {"pair_A": (15, "missed", "missed"), "pair_D": (7, "undecided", "missed")}


# ----- study validate on committed runs: the verdict given, never refused ------------------

@pytest.fixture(scope="module")
def validated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    folder = tmp_path_factory.mktemp("verdict")
    out = folder / "out"
    return out, main(validate_args(mini_study(folder, dict(STRICT)), out))


#: the shipped study's targets: this job's replay misses them (median 1.3 %)
STRICT = {"replay": {"median": 0.01, "worst": 0.03}, "prediction": {"median": 0.05, "worst": 0.15}}


def test_a_job_with_a_flagged_run_gets_a_verdict_and_a_missed_target_exits_1(validated, capsys):
    out, status = validated
    assert status == 1
    stats = json.loads((out / "errors.json").read_text())
    held = stats[verdict.HELD_OUT_TITLE]["verdict"]
    assert held["prediction"]["flagged_runs"] == 1  # xr_2gpu_host_copy: its probes 38 % apart
    assert held["replay"]["status"] == "missed" and held["status"] == "missed"
    assert "refused" not in json.dumps(stats)
    line = json.loads((out / verdict.FILE).read_text())["line"]
    assert line.startswith("Verdict on the 2 held-out configurations: a target missed. Replay")
    assert "band" in line and json.loads((out / verdict.FILE).read_text())["exit_status"] == 1
    report = (out / "report.md").read_text().splitlines()
    assert report[0].startswith("# mgpusim study") and report[2].startswith("**Verdict on the 2 held-out")


@pytest.mark.parametrize("targets, status", [(LOOSE, 0), (None, 0)])
def test_met_targets_and_no_targets_exit_0(tmp_path: Path, capsys, targets, status):
    out = tmp_path / "out"
    assert main(validate_args(mini_study(tmp_path, targets), out, "--no-figures")) == status
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1].startswith("Verdict on the 2 held-out configurations: "
                                  + ("every target met" if targets else "no target set"))


def test_an_empty_runs_folder_is_refused_as_bad_input(tmp_path: Path, capsys):
    empty = tmp_path / "runs"
    empty.mkdir()
    assert main(["study", "validate", str(mini_study(tmp_path)), "--held-out", "--runs", str(empty),
                 "--out", str(tmp_path / "out")]) == 2
    assert "holds no measured run" in capsys.readouterr().err
    assert not (tmp_path / "out" / "report.md").exists()


# ----- main and study run: the same rule (the measuring replaced by the committed job) -----

def _offline_run(study, out: Path, progress, held_out: bool = True, devices=None) -> Path:
    """pipeline.run on the committed job: its runs validated instead of measured."""
    speeds: pipeline.SpeedTables = {}
    tables, missing = {}, {}
    for title, entries in ((pipeline.CALIBRATION_TITLE, study.calibration), (pipeline.HELD_OUT_TITLE, study.held_out)):
        if entries and (held_out or title == pipeline.CALIBRATION_TITLE):
            tables[title] = pipeline.validate(study, entries, JOB / "runs", JOB / "profile.toml", out / "validation",
                                              progress, figures=False, speed_tables=speeds)
            missing[title] = pipeline.without_runs(entries, JOB / "runs")
    return pipeline.write_report(out, study, tables, "fit", None, missing, run_speed.read(JOB / "runs" / run_speed.FILE))


@pytest.mark.parametrize("targets, status", [(STRICT, 1), (LOOSE, 0)])
def test_main_and_study_run_exit_alike(tmp_path: Path, monkeypatch, capsys, targets, status):
    monkeypatch.setattr(pipeline, "run", _offline_run)
    study = mini_study(tmp_path, targets)
    assert main(["main", "--held-out", "--study", str(study), "--out", str(tmp_path / "m")]) == status
    line_main = capsys.readouterr().out.strip().splitlines()[-1]
    assert main(["study", "run", str(study), "--held-out", "--out", str(tmp_path / "s")]) == status
    line_run = capsys.readouterr().out.strip().splitlines()[-1]
    assert line_main == line_run and line_main.startswith("Verdict on the 2 held-out configurations")


def test_main_and_study_run_exit_3_when_nothing_could_be_measured(tmp_path: Path, monkeypatch, capsys):
    def no_device(*args, **kwargs):
        raise DependencyError("Vulkan found no device; install lavapipe")
    monkeypatch.setattr(pipeline, "run", no_device)
    study = mini_study(tmp_path)
    for argv in (["main", "--study", str(study), "--out", str(tmp_path / "m")],
                 ["study", "run", str(study), "--out", str(tmp_path / "s")]):
        assert main(argv) == 3
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1] == "could not measure: Vulkan found no device; install lavapipe"


def test_bad_input_still_exits_2(tmp_path: Path, capsys):
    assert main(["study", "run", str(tmp_path / "nope.toml")]) == 2
    assert main(["main", "--study", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "m")]) == 2


# ----- the page: the verdict first, the flag column on screen ------------------------------

#: Where the verdict paragraph and the speed-flag heading of the first table with one lie, and
#: what the window shows: read in the page (CSS pixels).
_GEOMETRY = """(() => {
  const v = document.getElementById('verdict');
  const h1 = document.querySelector('h1');
  const flag = Array.from(document.querySelectorAll('th')).find(th => th.textContent === 'speed flag');
  flag.scrollIntoView({block: 'center'});
  const f = flag.getBoundingClientRect(), box = flag.closest('div.wide').getBoundingClientRect();
  return {verdict: v.textContent, verdictTop: v.getBoundingClientRect().top + window.scrollY,
          afterTitle: h1.nextElementSibling === v, flagLeft: f.left, flagRight: f.right,
          flagTop: f.top, flagBottom: f.bottom, boxRight: box.right, width: window.innerWidth,
          height: window.innerHeight, pageWide: document.documentElement.scrollWidth};
})()"""


@pytest.mark.skipif(find_browser() is None, reason=NO_BROWSER)
def test_the_page_opens_on_the_verdict_and_shows_the_flag_column(validated, tmp_path: Path):
    out, _ = validated
    png, seen = screenshot(out / "report.html", find_browser(), _GEOMETRY, width=1280, height=800)
    (tmp_path / "flag_column.png").write_bytes(png)
    assert seen["afterTitle"] and seen["verdict"].startswith("Verdict on the 2 held-out configurations")
    assert seen["verdictTop"] < 150  # the first thing under the title
    # the flag column lies inside the window and its table's box: seen without scrolling sideways
    assert 0 <= seen["flagLeft"] < seen["flagRight"] <= min(seen["width"], seen["boxRight"] + 1)
    assert 0 <= seen["flagTop"] < seen["flagBottom"] <= seen["height"]
    assert seen["pageWide"] <= seen["width"]  # the page itself never scrolls sideways
    assert _png_size(png) == (1280, 800)


@pytest.mark.skipif(find_browser() is None, reason=NO_BROWSER)
def test_a_narrow_window_scrolls_the_table_in_its_box_not_the_page(validated):
    out, _ = validated
    _, seen = screenshot(out / "report.html", find_browser(), _GEOMETRY, width=700, height=800)
    assert seen["pageWide"] <= seen["width"] and seen["verdictTop"] < 250


def _png_size(png: bytes) -> tuple[int, int]:
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and zlib.crc32(png[12:29]) == struct.unpack(">I", png[29:33])[0]
    return struct.unpack(">II", png[16:24])
