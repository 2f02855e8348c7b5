"""A study's steps: measure -> calibrate -> validate -> report, each usable on its own.

`run` does all four into one output folder (what `mgpusim main` does for the lavapipe study);
`calibrate` and `validate` also work on committed runs with no device (the NVIDIA studies).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import tomli_w

from mgpusim.calibration.recipe import profile_from_tables, refine_on_runs
from mgpusim.io.plot import errors_png
from mgpusim.io.workers import in_workers
from mgpusim.io.writers import write_json
from mgpusim.measure import run_archive, run_speed, speed_norm
from mgpusim.measure import speed_probe as speed
from mgpusim.measure.speed_norm import RunSpeed
from mgpusim.studies import run_sets, verdict
from mgpusim.studies.measuring import Progress, measure_microbenchmarks, measure_runs, measured_folder
from mgpusim.studies.page import stats_line, write_study_page
from mgpusim.studies.study_file import Entry, Study
from mgpusim.studies.verdict import CALIBRATION_TITLE, HELD_OUT_TITLE
from mgpusim.validation.compare import error_stats, error_table
from mgpusim.validation.crossvalidate import format_report, validate_experiment
from mgpusim.validation.measured import read_measured

#: Each runs folder's speed record (`runs/run_speed.csv`) as one command read it, by folder.
SpeedTables = dict[Path, pd.DataFrame]


def runs_root(study: Study, held_out: bool, out: Path) -> Path:
    """Where a half's measured runs lie: the study's committed folder, or `out/runs`."""
    committed = study.held_out_runs if held_out else study.calibration_runs
    return committed if committed is not None else out / "runs"


def without_runs(entries: tuple[Entry, ...], root: Path) -> list[str]:
    """The names of the entries that have no measured run under `root`: listed in the fit
    report, the validation output and report.md, never left out silently."""
    return [e.name for e in entries if not run_archive.is_folder(measured_folder(root, e.name))]


def load_runs(study: Study, entries: tuple[Entry, ...], root: Path,
              profile: Path | None = None) -> list[tuple[Any, pd.DataFrame]]:
    """(experiment, measured trace) of every entry whose run lies under `root`."""
    runs = []
    for e in entries:
        folder = measured_folder(root, e.name)
        if run_archive.is_folder(folder):
            exp = e.load(profile or study.profile)
            runs.append((exp, read_measured(folder, exp)))
    return runs


def calibrate(study: Study, out: Path, progress: Progress, tables: list[Path] | None = None,
              runs_dir: Path | None = None, allow_missing: bool = False) -> tuple[Path, str]:
    """Fit the study's profile on its tables, then on its calibration runs (committed, under
    `runs_dir`, or under `out/runs`); write `out/profile.toml`; return it and the fit text.
    The runs are checked to be the study's own and complete (unless `allow_missing`) before
    any fit."""
    root = runs_dir or runs_root(study, False, out)
    run_sets.check_half(study, study.calibration, root, "--runs" if runs_dir else "",
                        allow_missing, "calibration")
    tables = tables or study.microbenchmarks.tables(out / "measurements")
    data, lines = profile_from_tables(study.recipe, tables, study.profile,
                                      f"mgpusim study calibrate {study.file}")
    progress(f"calibrate from {len(tables)} tables")
    return fit_on_runs(study, data, lines, root, out)


def fit_on_runs(study: Study, data: dict[str, Any], lines: list[str], root: Path, out: Path,
                profile: Path | None = None) -> tuple[Path, str]:
    """The recipe's run-based steps on the calibration runs under `root` (their experiments
    built on `profile`, default the study's); write `out/profile.toml` with the fit report."""
    runs = load_runs(study, study.calibration, root, profile)
    data, more = refine_on_runs(study.recipe, data, runs)
    missing = without_runs(study.calibration, root)
    if missing:
        more = more + [f"{len(missing)} calibration configuration(s) without a measured run under "
                       f"{root} (not in the fit): {', '.join(missing)}"]
    return write_profile(data, out / "profile.toml", lines + more), "\n".join(lines + more)


def write_profile(data: dict[str, Any], path: Path, lines: list[str]) -> Path:
    """The profile TOML with the fit report as its header comment, written whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    header = "# Calibrated by mgpusim study. Fit report:\n" + "".join(
        f"#   {line}\n" for text in lines for line in text.splitlines())
    tmp = path.with_suffix(".tmp")
    tmp.write_text(header + "\n" + tomli_w.dumps(data))
    tmp.replace(path)
    return path


def validate(study: Study, entries: tuple[Entry, ...], root: Path, profile: Path, out: Path,
             progress: Progress, extra: tuple[str, ...] = (), figures: bool = True,
             calibration_root: Path | None = None,
             speed_tables: SpeedTables | None = None) -> pd.DataFrame:
    """Compare each entry's measured run under `root` with the model on `profile` (no device
    needed); one row per entry with a run; `run_to_run_spread` where repeats were kept.
    `figures`: each entry's timelines and traces too (most of the time taken).
    `calibration_root`: where the calibration runs are (default `root`), whose speed records
    give the speed the profile was fitted at. `speed_tables`: the command's speed records
    already read (see :func:`speed_table`), so that its halves and report share one read."""
    rows = []
    missing = without_runs(entries, root)
    if missing:
        progress(f"no measured run under {root} for {len(missing)} configuration(s): {', '.join(missing)}")
    speeds = run_speeds(study, entries, root, calibration_root or root, speed_tables)
    jobs = [(e, profile, extra, measured_folder(root, e.name), out / e.name, speeds.get(e.name), figures)
            for e in entries if e.name not in missing]
    # independent, each writing its own folder; their timelines (matplotlib) take most of the time
    for name, report, text in in_workers(_validate_entry, jobs):
        progress(text)
        rows.append((name, report))
    table = error_table([r for _, r in rows])
    if rows:
        table["schedule"] = [name for name, _ in rows]
        table["run_to_run_spread"] = [r["measured_spread"] for _, r in rows]
        table = table.join(pd.DataFrame([most_off(r) for _, r in rows], index=table.index))
    return table


def _validate_entry(e: Entry, profile: Path, extra: tuple[str, ...], folder: Path, out: Path,
                    speed: RunSpeed | None, figures: bool) -> tuple[str, dict[str, Any], str]:
    """One entry's comparison written to `out`: its schedule's name, report and text."""
    exp = e.load(profile, extra)
    report = validate_experiment(exp, out, folder, speed=speed, figures=figures)
    report["config"] = e.name
    return exp.schedule.name, report, format_report(exp, report)


def speed_table(tables: SpeedTables, root: Path) -> pd.DataFrame:
    """The speed record under `root`, read on first use and kept in `tables`. Why: one
    `study validate --held-out` needs the calibration folder's record for each half's reference
    and for the report; reading it once (maybe from a packed archive) keeps it one table."""
    if root not in tables:
        tables[root] = run_speed.read(root / run_speed.FILE)
    return tables[root]


def run_speeds(study: Study, entries: tuple[Entry, ...], root: Path,
               calibration_root: Path, tables: SpeedTables | None = None) -> dict[str, RunSpeed]:
    """Per entry with a speed record under `root` (a lavapipe job's `runs/run_speed.csv`), its
    compared run's speed against the probe at calibration: the median over the study's
    calibration runs, from the records under `calibration_root` ({} where there are none).
    `tables`: records the caller already read, and where this one keeps those it reads."""
    tables = {} if tables is None else tables
    table = speed_table(tables, root)
    if table.empty:
        return {}
    cal = speed_table(tables, calibration_root)
    ref = speed_norm.reference_ms(cal, [(e.name, run_speed.compared_run(calibration_root, e.name))
                                        for e in study.calibration])
    if ref is None:
        return {}
    speeds = {e.name: speed_norm.speed_row(table, e.name, run_speed.compared_run(root, e.name), ref)
              for e in entries}
    return {name: sp for name, sp in speeds.items() if sp is not None}


def most_off(report: dict[str, Any]) -> dict[str, Any]:
    """Where one comparison differs most: the step whose mean duration is furthest off in ms
    (simulated - measured, and as simulated / measured - 1) and the hand-off whose mean wait
    from ready to start is (measured - simulated ms; none where no wait was compared). Why: a
    frame-time error says how far the model is off, these say where to look for the effect it
    lacks; in ms, since a tiny step far off in % moves a frame little."""
    steps = report.get("steps", {})
    step = max(steps, key=lambda k: (abs(_step_ms(steps[k])), k), default="")
    waits = report.get("waits", {})
    edge = next(iter(waits), "")  # sorted by |difference|, largest first
    return {"step_most_off": step,
            "step_difference_ms": _step_ms(steps[step]) if step else float("nan"),
            "step_error": steps[step]["error"] if step else float("nan"),
            "wait_most_off": edge,
            "wait_difference_ms": waits[edge]["difference_ms"] if edge else float("nan")}


def run(study: Study, out: Path, progress: Progress, held_out: bool = True,
        devices: list[int] | None = None) -> Path:
    """Measure, calibrate, validate and report the whole study into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    tables = None
    if study.microbenchmarks.sweeps and study.microbenchmarks.folder is None:
        tables = measure_microbenchmarks(study, out / "measurements", progress)
    command = f"mgpusim study run {study.file}"
    data, lines = profile_from_tables(study.recipe, tables or study.microbenchmarks.tables(out / "measurements"),
                                      study.profile, command)
    base = write_profile(data, out / "profile_microbenchmarks.toml", lines)
    measure_runs(study, study.entries(held_out), base, out / "runs", progress, devices)
    run_sets.check_half(study, study.calibration, out / "runs", "", False, "calibration")
    progress("calibrate from runs")
    profile, fit_text = fit_on_runs(study, data, lines, out / "runs", out, base)
    speeds: SpeedTables = {}  # after the runs are measured: read once, shared below
    tables_out = {CALIBRATION_TITLE: validate(study, study.calibration, out / "runs", profile,
                                              out / "validation", progress, speed_tables=speeds)}
    missing = {CALIBRATION_TITLE: without_runs(study.calibration, out / "runs")}
    if held_out and study.held_out:
        tables_out[HELD_OUT_TITLE] = validate(study, study.held_out, out / "runs", profile,
                                              out / "validation", progress, speed_tables=speeds)
        missing[HELD_OUT_TITLE] = without_runs(study.held_out, out / "runs")
    return write_report(out, study, tables_out, fit_text, probes_of(out / "runs"), missing,
                        speed_table(speeds, out / "runs"))


def probes_of(runs: Path) -> pd.DataFrame:
    """The speed probes of the job whose runs lie in `runs` (and its tables beside them)."""
    return speed.read_probes([runs.parent / "measurements" / speed.FILE, runs / speed.FILE])


#: report.md's paragraph on how to read it (after the verdict line).
INTRO = ("Errors are simulated / measured - 1, at two levels. The *replay* (the verdict's headline) is "
         "the model's timeline with every task taking the duration the run measured for it: what "
         "is left is the timeline's own error, which the machine's speed cannot move. The "
         "*prediction* is the calibrated cost model; on lavapipe each run is also predicted at its "
         "own probed speed (`normalized`). A prediction's *band* is how far the run's own "
         "measurements let its error move: the speed probes just before and after the run (the "
         "machine's speed during it lies between them) and the spread of its interleaved repeats "
         "(docs/validation.md, \"The verdict\"). The measured side is the steady window of the "
         "repeats; `spread` is slowest / fastest - 1 of the repeats' frame times, the machine's own "
         "noise. Each configuration's timelines show the measured run above the simulated one, "
         "same frames, one time axis (unless `--no-figures`).")


def write_report(out: Path, study: Study, tables: dict[str, pd.DataFrame], fit_text: str,
                 probes: pd.DataFrame | None = None,
                 missing: dict[str, list[str]] | None = None,
                 run_speeds: pd.DataFrame | None = None) -> Path:
    """report.md: the verdict first (:mod:`mgpusim.studies.verdict`: the replay against its
    target, the prediction with its band), the machine's speed during the job (its probes,
    when measured, and each run's from `run_speeds`, runs/run_speed.csv); per half the
    configurations without a measured run (`missing`), its error plot, and per schedule the
    error tables, their statistics and the measured/simulated timelines with both traces;
    errors.json (per half, with its verdict and the configurations without runs),
    errors_by_schedule.json (the errors alone, as the committed NVIDIA tables hold them),
    verdict.json (the job's line and exit status), errors_*.csv,
    errors_*.png; and report.html, the same Markdown as a static page (mgpusim/studies/page.py)."""
    out.mkdir(parents=True, exist_ok=True)
    stats: dict[str, Any] = {}
    by_schedule: dict[str, dict[str, Any]] = {}
    schedule_verdicts: dict[tuple[str, str], dict[str, Any]] = {}  # report.md's, per schedule
    for title, table in tables.items():
        absent = (missing or {}).get(title, [])
        if absent:
            stats.setdefault(title, {})["without_runs"] = absent
        if table.empty:
            continue
        stats[title] = {**error_stats(table), "verdict": verdict.half_verdict(table, study.targets),
                        **stats.get(title, {})}
        for schedule, part in _groups(table):  # errors_by_schedule.json: the errors alone
            by_schedule.setdefault(title, {})[schedule] = error_stats(part)
            schedule_verdicts[(title, schedule)] = verdict.half_verdict(part, study.targets)
    head, rest = verdict.verdict_parts(stats)
    lines = [f"# mgpusim study {study.name}: measured vs simulated", "", f"**{head}** {rest}".strip(), "",
             *_missing_lines(missing or {}), INTRO, ""]
    speed_lines = speed.report_lines(probes if probes is not None else speed.read_probes([]))
    speed_lines += run_speed.report_lines(run_speeds if run_speeds is not None else pd.DataFrame())
    lines += speed_lines
    for title, table in tables.items():
        lines += [f"## {title}", ""]
        absent = (missing or {}).get(title, [])
        if absent:
            lines += [f"No measured run, not compared: {', '.join(absent)}.", ""]
        if table.empty:
            continue
        half = title.split()[0].lower()
        errors_png(table, out / f"errors_{half}.png", title)
        lines += [stats_line(stats[title]), "",
                  f"![frame-time error per configuration: prediction and replay](errors_{half}.png)", ""]
        for schedule, part in _groups(table):
            st = {**by_schedule[title][schedule], "verdict": schedule_verdicts[(title, schedule)]}
            lines += [f"### {title.split(' (')[0]}: {schedule}", "", stats_line(st), "",
                      markdown_table(part), ""]
            lines += _figure_lines(out, part)
        table.to_csv(out / f"errors_{half}.csv", index=False)
    lines += ["## Calibration", "", "```", fit_text, "```", ""]
    write_json(stats, out / "errors.json")
    write_json(by_schedule, out / "errors_by_schedule.json")
    write_json({"half": verdict.chosen_half(stats), "line": verdict.verdict_line(stats),
                "exit_status": verdict.exit_status(stats)}, out / verdict.FILE)
    files = [f.name for f in sorted(out.glob("errors*.json")) + sorted(out.glob("errors_*.csv"))]
    lines += ["## Files", "", *[f"- [{name}]({name})" for name in [verdict.FILE, *files]],
              "- [report.md](report.md): this report in Markdown; report.html is the same as a page", ""]
    text = "\n".join(lines)
    path = out / "report.md"
    path.write_text(text)
    write_study_page(out, text)
    return path


def _missing_lines(missing: dict[str, list[str]]) -> list[str]:
    """The configurations left out for want of a run, right under the verdict: a verdict on
    part of a study must say so before anything else."""
    absent = [(title, names) for title, names in missing.items() if names]
    if not absent:
        return []
    parts = "; ".join(f"{title.split(' (')[0].lower()}: {len(names)} ({', '.join(names)})"
                      for title, names in absent)
    return [f"**Not every configuration was compared** (no measured run): {parts}.", ""]


def _groups(table: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """The table's rows per schedule, in the order they first appear."""
    if "schedule" not in table:
        return [("", table)]
    return [(str(name), part) for name, part in table.groupby("schedule", sort=False)]


def _figure_lines(out: Path, part: pd.DataFrame) -> list[str]:
    """Each configuration's timelines and links to both Perfetto traces (those written: none
    with `--no-figures`)."""
    lines = []
    for config in part["config"]:
        folder = out / "validation" / str(config)
        if (folder / "timelines.png").exists():
            lines += [f"![{config}: measured above, simulated below](validation/{config}/timelines.png)", ""]
        traces = [f"[{side} trace](validation/{config}/{side}.perfetto.json)" for side in ("measured", "simulated")
                  if (folder / f"{side}.perfetto.json").exists()]
        if traces:
            lines += [f"{config}: {', '.join(traces)} (open in https://ui.perfetto.dev)", ""]
    return lines


#: The frame-time table's columns: (heading, alignment); the speed columns where runs were probed.
_FRAME_HEAD = ("config", "measured (ms)", "predicted (ms)", "error", "replay error", "spread")
_SPEED_HEAD = ("probe ratio", "normalized error")
_LATENCY_HEAD = ("config", "measured latency (ms)", "predicted (ms)", "error", "replay error", "stalls left out",
                 "step most off (simulated - measured)", "hand-off most off (measured - simulated)")


def markdown_table(table: pd.DataFrame) -> str:
    """Two tables narrow enough for a page: the frame time (with the band and, on a lavapipe
    job, the speed columns and flag), then the latency and where each configuration is most off."""
    probed = "probe_ratio" in table
    head = [*_FRAME_HEAD, *(_SPEED_HEAD if probed else ()), "band", *(("speed flag",) if probed else ())]
    rows = [_row(head), _rule(head)]
    bands = verdict.band(table)
    for r, lo, hi in zip(table.itertuples(), bands["lo"].tolist(), bands["hi"].tolist()):
        spread = getattr(r, "run_to_run_spread", float("nan"))
        rep = getattr(r, "replay_frame_time_error", float("nan"))
        cells = [str(r.config), f"{r.measured_frame_ms:.2f}", f"{r.simulated_frame_ms:.2f}",
                 f"{r.frame_time_error:+.1%}", f"{rep:+.1%}", f"{spread:.0%}"]
        if probed:
            cells += _speed_cells(r)
        cells.append(f"{lo:+.1%} to {hi:+.1%}")
        if probed:
            cells.append(_flag_cell(r))
        rows.append(_row(cells))
    latency = [_row(_LATENCY_HEAD), _rule(_LATENCY_HEAD)]
    for r in table.itertuples():
        stalls = getattr(r, "stalled_frames", 0)
        rep_lat = getattr(r, "replay_latency_error", float("nan"))
        latency.append(_row([str(r.config), f"{r.measured_latency_ms:.2f}", f"{r.simulated_latency_ms:.2f}",
                             f"{r.latency_error:+.1%}", f"{rep_lat:+.1%}", str(stalls or ""), _step_cell(r),
                             _wait_cell(r)]))
    return "\n".join(rows) + "\n\n" + "\n".join(latency)


def _row(cells: Any) -> str:
    return "| " + " | ".join(cells) + " |"


def _rule(head: Any) -> str:
    """The header rule: text columns left, numbers right."""
    text = {"config", "speed flag", "band", "stalls left out", "step most off (simulated - measured)",
            "hand-off most off (measured - simulated)"}
    return "|" + "|".join("---" if h in text else "---:" for h in head) + "|"


def _speed_cells(r: Any) -> list[str]:
    """Probe ratio and normalized frame-time error (blank where the run has no probe)."""
    if pd.isna(r.probe_ratio):
        return ["", ""]
    return [f"{r.probe_ratio:.2f}", f"{r.normalized_frame_time_error:+.1%}"]


def _flag_cell(r: Any) -> str:
    """Why the speed rule flagged the run, in a few words ('' where it did not)."""
    flag = getattr(r, "speed_flag", "")
    if not isinstance(flag, str) or not flag:
        return ""
    words = []
    moved = getattr(r, "probe_disagreement", float("nan"))
    others = getattr(r, "other_cores", float("nan"))
    if moved > speed_norm.DISAGREEMENT_LIMIT:
        words.append(f"moved {moved:.0%}")
    if others > speed_norm.OTHER_CORES_LIMIT:
        words.append(f"others {others:.2f} cores")
    return "**flagged**: " + (", ".join(words) or flag)


def _step_ms(step: dict[str, float]) -> float:
    return step["simulated_ms"] - step["measured_ms"]


def _step_cell(r: Any) -> str:
    step = getattr(r, "step_most_off", "")
    return (f"{step} {r.step_difference_ms:+.2f} ms ({r.step_error:+.0%})"
            if isinstance(step, str) and step else "")


def _wait_cell(r: Any) -> str:
    edge = getattr(r, "wait_most_off", "")
    return f"`{edge}` {r.wait_difference_ms:+.2f} ms" if isinstance(edge, str) and edge else ""
