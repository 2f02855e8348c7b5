"""Does `mgpusim advise` rank a frame's options as real GPUs do? Capture, import, advise, run.

For each frame of a :class:`Setup` (an experiment and the overrides of its one-GPU capture):
1. the frame is captured: its one-GPU configuration runs for real (the runner's measured run)
   and the run is imported (`frame import`, the setup's profile);
2. the import is advised (up to `max_gpus`, the profile's own link: a real machine has no other);
3. the one-GPU baseline and the best confirmed option of each schedule family (and of each
   GPU count, where that gives too few: :func:`candidates`) are mapped back
   to the frame's own experiment (the option's [schedule] table) and run for real in `repeats`
   interleaved rounds, each with its own capture (the baseline; round 1's is the one advised),
   the fastest run of each option kept. A machine's speed can move (a shared VM), so the
   options are predicted again (full fidelity) from the fastest round's capture;
4. the predicted order is compared with the measured one. Options predicted within `tie` of
   each other count as tied: any measured order among them matches.

Why one module for every machine: the lavapipe and the NVIDIA runs differ only in frames,
profile, GPU count and devices (their entry points: tools/advise_validation/).

Written under OUT as it goes, so that a run cut short keeps what it measured and a second call
resumes it: `runs.csv` (one row per real run, appended), `frames/<frame>.csv` (a frame's table,
written when the frame is done; a frame with one is skipped), `frames/<frame>_advice.csv` (the
advice's options), `log.txt`; then `results.csv` (every finished frame's table: option,
measured and predicted frame time, the prediction from the frame's own experiment,
`source_predicted_ms`, which tells an error of the import from one of the model, ranks) and
`summary.txt`.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence, cast

import pandas as pd

from mgpusim.advise.advisor import Advice, Link, evaluate, search
from mgpusim.io import table_files
from mgpusim.io.writers import write_measured, write_text
from mgpusim.model.errors import MgpusimError
from mgpusim.schedules.binding import COLOUR_PIXEL_BYTES
from mgpusim.schedules.experiment import load_experiment
from mgpusim.sim.simulation import simulate

#: The only link a real machine has: its profile's own.
OWN_LINK = Link("as profiled", {}, "the profile's own link")
RUN_FIELDS = ("frame", "round", "option", "family", "gpus", "measured_ms", "latency_ms", "wall_s", "error")


@dataclass(frozen=True)
class Frame:
    """A frame to validate: `experiment` and the overrides (`capture`) that make it one GPU's."""

    name: str
    experiment: Path
    capture: Mapping[str, Any]

    @property
    def slug(self) -> str:
        return self.name.replace(" ", "_")


@dataclass(frozen=True)
class Setup:
    """What differs between machines: the profile every frame runs with (it replaces the
    experiments' own), the frames, how far to advise and how to run."""

    profile: Path
    frames: tuple[Frame, ...]
    max_gpus: int
    repeats: int = 2
    #: physical device of simulated GPU i (None: the runner's default, i mod count)
    devices: tuple[int, ...] | None = None
    #: the least frames of every real run (after the runner's untimed pre-warm frames)
    frames_per_run: int = 40
    #: predicted frame times closer than this share are a tie (no order is predicted)
    tie: float = 0.05
    #: processes of the advice's search (None: one per core)
    workers: int | None = None
    #: the simulator stands in for every real run: the whole path offline (a test of the logic
    #: and of the frames' options, no measurement)
    dry_run: bool = False


class Log:
    """Progress lines on stdout and in OUT/log.txt, each with the seconds since the start."""

    def __init__(self, out: Path):
        out.mkdir(parents=True, exist_ok=True)
        self.path, self.t0 = out / "log.txt", time.perf_counter()

    def __call__(self, text: str) -> None:
        line = f"[{time.perf_counter() - self.t0:7.1f}s] {text}"
        print(line, flush=True)
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(line + "\n")


# ----- real runs --------------------------------------------------------------------------------
def measure(setup: Setup, path: Path, overrides: Mapping[str, Any], out: Path | None = None) -> dict[str, float]:
    """One real run of the experiment at `path` under `overrides` (the setup's profile and
    devices): its mean period and latency; the run's files under `out` if given."""
    from mgpusim.real.runner.execute import run_experiment  # noqa: PLC0415

    first = load_experiment(path, overrides, profile=setup.profile)
    frames = max(setup.frames_per_run, int(first.schedule.warmup_frames) + 20)
    exp = load_experiment(path, {**overrides, "schedule.frames": frames}, profile=setup.profile)
    devices = list(setup.devices[:exp.schedule.gpus]) if setup.devices else None
    result = _simulated_run(exp) if setup.dry_run else run_experiment(exp, devices=devices)
    if out is not None:
        write_measured(result, out, "csv")
    return {"frame_time_ms": result.summary["frame_time_ms"], "latency_ms": result.summary["latency_ms"]}


def _simulated_run(exp: Any) -> SimpleNamespace:
    """The simulation of `exp` shaped as a measured run (what write_measured takes)."""
    got = simulate(exp)
    return SimpleNamespace(trace=got.trace, frames=got.frames, submissions=None, summary=got.summary,
                           config={**got.config, "measured": False}, machine={"dry_run": True})


def capture_frame(setup: Setup, frame: Frame, folder: Path) -> tuple[Path, float]:
    """Run the frame on one GPU for real and import the run: (the experiment, its frame time)."""
    from mgpusim.frames.formats import read_run  # noqa: PLC0415
    from mgpusim.frames.importer import experiment_text, frame_from_slices  # noqa: PLC0415

    got = measure(setup, frame.experiment, frame.capture, folder)
    slices, meta = read_run(folder)
    captured = frame_from_slices(slices, name=frame.slug, source=str(folder), width=meta["width"],
                                 height=meta["height"], origin=meta["source"])
    toml = folder.with_suffix(".toml")
    write_text(experiment_text(captured, setup.profile, toml), toml)
    return toml, got["frame_time_ms"]


# ----- options on the frame's own experiment ----------------------------------------------------
def source_overrides(setup: Setup, frame: Frame, schedule: Mapping[str, Any]) -> dict[str, Any]:
    """An option's [schedule] table for the frame's own experiment, beside the capture's scene
    overrides: the schedule as advised, AFR's history size left to its default (the frame's
    colour image, what was captured); under pipelining every pass's output is its colour image
    (what the import gave each pass the runner renders; a mesh's copy then leaves its depth
    behind, which no later pass reads), which the runner needs to copy it."""
    scene = {k: v for k, v in frame.capture.items() if not k.startswith("schedule.")}
    sched = {k: v for k, v in schedule.items() if k != "history_bytes"}
    out: dict[str, Any] = {**scene, "schedule": sched}
    if sched["name"] == "pipelining":
        exp = load_experiment(frame.experiment, scene, profile=setup.profile)
        out["scene.passes.*.output_bytes"] = exp.scene.pixels * COLOUR_PIXEL_BYTES
    return out


def candidates(advice: Advice, least: int = 4) -> list[int]:
    """The baseline and the best confirmed option of each family (runnable: the frame's own
    scene, not a two-eye copy of it, and not paced, which the runner cannot: its pacer is CPU
    work); where that makes fewer than `least` (a stereo frame has only XR), the best of each
    family and GPU count too, best first, up to `least`."""
    ranked = advice.ranked
    ranked = ranked[[("scene.passes" not in advice.options[i].overrides and advice.options[i].paced_from is None)
                     for i in ranked.index]]
    chosen = {0, *ranked.groupby("family", sort=False).head(1).index}
    for index in ranked.groupby(["family", "gpus"], sort=False).head(1).index:
        if len(chosen) >= least:
            break
        chosen.add(index)
    return sorted(chosen)


def source_prediction(setup: Setup, frame: Frame, advice: Advice, index: int) -> float:
    """The option simulated on the frame's own experiment (its real passes, the profile's
    fitted costs): where it and the prediction from the capture agree, a wrong order is the
    model's on this machine, not the import's."""
    over = dict(frame.capture) if index == 0 else \
        source_overrides(setup, frame, advice.options[index].overrides["schedule"])
    try:
        exp = load_experiment(frame.experiment, over, profile=setup.profile)
        return simulate(exp, record_trace=False).summary["frame_time_ms"]
    except MgpusimError:
        return math.nan


# ----- one frame ----------------------------------------------------------------------------------
def one_frame(setup: Setup, frame: Frame, out: Path, log: Callable[[str], None]) -> pd.DataFrame:
    """Capture, advise, then `repeats` interleaved rounds of a capture and the candidates; the
    prediction is made again from the round whose capture ran fastest (the machine's quietest
    moment), so capture and measurements share the machine's state."""
    folder = out / "frames" / frame.slug
    log(f"[{frame.name}] capturing {frame.experiment.name} on one GPU")
    toml, first_ft = capture_frame(setup, frame, folder / "capture1")
    t0 = time.perf_counter()
    advice = search(toml, max_gpus=setup.max_gpus, links=(OWN_LINK,), workers=setup.workers)
    log(f"[{frame.name}] advised {advice.counts['options']} options in {time.perf_counter() - t0:.1f} s "
        f"(baseline {advice.baseline['frame_time_ms']:.3f} ms)")
    advice.table.drop(columns=["error"]).join(advice.table["error"].str.slice(0, 160)).to_csv(
        out / "frames" / f"{frame.slug}_advice.csv")
    picks = candidates(advice)
    rows = [{"frame": frame.name, "option": advice.options[i].label, "family": advice.options[i].family,
             "gpus": advice.options[i].gpus} for i in picks]
    captures = [(first_ft, toml)]
    for r in range(1, setup.repeats + 1):  # interleaved: a slow spell of the machine hits every option
        if r > 1:
            captures.append(capture_frame(setup, frame, folder / f"capture{r}")[::-1])
        for row, index in zip(rows, picks):
            got = _measure_option(setup, frame, advice, index, captures[-1][0])
            ident = {k: row[k] for k in ("frame", "option", "family", "gpus")}
            _append_run(out, {**ident, "round": r, **got})  # this round's run alone
            log(f"[{frame.name}] round {r}: {row['option']}: "
                + (f"{got['measured_ms']:.3f} ms" if not got.get("error") else f"failed: {got['error']}"))
            if got.get("error"):
                if "measured_ms" not in row:  # no round measured it yet: the error stands
                    row["error"] = got["error"]
            elif got["measured_ms"] < row.get("measured_ms", math.inf):
                row["measured_ms"] = got["measured_ms"]
                row.pop("error", None)  # an earlier round's failure is in runs.csv
    quiet = min(captures, key=lambda c: c[0])[1]
    return _table(setup, frame, advice, picks, rows, quiet)


def _measure_option(setup: Setup, frame: Frame, advice: Advice, index: int, capture_ms: float) -> dict[str, Any]:
    """A candidate's real run (the baseline's is the round's capture): measured_ms, latency_ms,
    wall_s, or the error that stopped it."""
    t0 = time.perf_counter()
    if index == 0:
        return {"measured_ms": capture_ms, "latency_ms": math.nan, "wall_s": 0.0}
    over = source_overrides(setup, frame, advice.options[index].overrides["schedule"])
    try:
        got = measure(setup, frame.experiment, over)
    except Exception as exc:  # noqa: BLE001 - one option the runner cannot run stops no other
        return {"error": f"{type(exc).__name__}: {exc}"[:160], "wall_s": time.perf_counter() - t0}
    return {"measured_ms": got["frame_time_ms"], "latency_ms": got["latency_ms"],
            "wall_s": time.perf_counter() - t0}


def _table(setup: Setup, frame: Frame, advice: Advice, picks: list[int], rows: list[dict[str, Any]],
           quiet: Path) -> pd.DataFrame:
    """The frame's table: predicted from the quietest capture, measured, ranks, errors."""
    predicted = {p["option"]: p for p in evaluate(str(quiet), {}, [(i, advice.options[i].overrides)
                                                                  for i in picks], "full")}
    for row, index in zip(rows, picks):
        row["predicted_ms"] = predicted[index]["frame_time_ms"]
        row["predicted_latency_ms"] = predicted[index]["latency_ms"]
        row["advised_rank"] = int(cast(int, advice.table.loc[index, "rank"]))
        row["source_predicted_ms"] = source_prediction(setup, frame, advice, index)
    table = pd.DataFrame(rows)
    for col in ("measured_ms", "error"):
        if col not in table:
            table[col] = math.nan if col == "measured_ms" else None
    table["predicted_rank"] = table["predicted_ms"].rank(method="first").astype("Int64")  # NaN: not predicted
    table["measured_rank"] = table["measured_ms"].rank(method="first")
    table["error_pct"] = 100 * (table["predicted_ms"] / table["measured_ms"] - 1)
    table["order_matches"] = order_matches(table, setup.tie)
    return table


def order_matches(table: pd.DataFrame, tie: float) -> bool:
    """Every pair of measured options predicted more than `tie` apart is measured in the same
    order."""
    agree, pairs = pair_agreement(table, tie)
    return agree == pairs


def pair_agreement(table: pd.DataFrame, tie: float) -> tuple[int, int]:
    """(pairs measured in the predicted order, pairs predicted more than `tie` apart), over the
    options that were measured."""
    ok = table.dropna(subset=["measured_ms", "predicted_ms"])
    pred, meas = ok["predicted_ms"].to_numpy(float), ok["measured_ms"].to_numpy(float)
    agree = pairs = 0
    for a in range(len(ok)):
        for b in range(len(ok)):
            if pred[a] < pred[b] * (1 - tie):
                pairs += 1
                agree += int(meas[a] < meas[b])
    return agree, pairs


def _append_run(out: Path, row: Mapping[str, Any]) -> None:
    """One real run's row, appended to runs.csv at once (what a cut-short call leaves)."""
    path = out / "runs.csv"
    new = not path.exists()
    with path.open("a", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=RUN_FIELDS, extrasaction="ignore")
        if new:
            writer.writeheader()
        writer.writerow({k: row.get(k, "") for k in RUN_FIELDS})


# ----- the whole run --------------------------------------------------------------------------
def validate(setup: Setup, out: Path, *, only: str | None = None, deadline_s: float | None = None,
             log: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Every frame of `setup` (those whose name contains `only`) not done yet under `out`; none
    starts after `deadline_s` seconds. Returns the finished frames' results (results.csv)."""
    log = log or Log(out)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for frame in setup.frames:
        done = out / "frames" / f"{frame.slug}.csv"
        if (only and only not in frame.name) or done.exists():
            continue
        if deadline_s is not None and time.perf_counter() - t0 > deadline_s:
            log(f"[{frame.name}] not started: past the deadline of {deadline_s:.0f} s")
            continue
        table = one_frame(setup, frame, out, log)
        write_text(table.round(4).to_csv(index=False), done)  # whole or not at all: done means done
        with pd.option_context("display.width", 220, "display.max_columns", 20):
            log(f"[{frame.name}] done\n" + table.drop(columns=["frame"]).round(3).to_string(index=False))
    return collect(setup, out, log)


def collect(setup: Setup, out: Path, log: Callable[[str], None] = print) -> pd.DataFrame:
    """The finished frames' tables as results.csv, and the summary line in summary.txt."""
    parts = [table_files.read_csv(out / "frames" / f"{f.slug}.csv", ends_whole=True) for f in setup.frames
             if (out / "frames" / f"{f.slug}.csv").exists()]
    if not parts:
        log("no frame finished")
        return pd.DataFrame()
    results = pd.concat(parts, ignore_index=True)
    write_text(results.to_csv(index=False), out / "results.csv")
    text = summary(results, setup.tie)
    write_text(text + "\n", out / "summary.txt")
    log(text + f"; wrote {out / 'results.csv'}")
    return results


def summary(results: pd.DataFrame, tie: float) -> str:
    """How often the predicted order held, over frames and over pairs of options."""
    per_frame = results.groupby("frame", sort=False)["order_matches"].first()
    agree = pairs = 0
    for _, table in results.groupby("frame", sort=False):
        a, p = pair_agreement(table, tie)
        agree, pairs = agree + a, pairs + p
    err = results["error_pct"].abs().median()
    return (f"predicted order matches the measured one on {int(per_frame.sum())} of {len(per_frame)} "
            f"frames and {agree} of {pairs} pairs of options predicted more than {tie:.0%} apart; "
            f"median |error| of the frame time {err:.1f} %")


def frames_of(rows: Sequence[tuple[str, Path, Mapping[str, Any]]]) -> tuple[Frame, ...]:
    """Frames from (name, experiment, capture overrides) rows."""
    return tuple(Frame(name, Path(path), dict(capture)) for name, path, capture in rows)


def main(setup: Setup, description: str, argv: Sequence[str] | None = None) -> int:
    """The entry points' command line: --out, --repeats, --only, --deadline-s."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--out", type=Path, required=True, help="folder of the results (resumed if it has some)")
    parser.add_argument("--repeats", type=int, default=setup.repeats, help="interleaved rounds of real runs")
    parser.add_argument("--only", default=None, help="frames whose name contains this")
    parser.add_argument("--deadline-s", type=float, default=None, help="no frame starts after this")
    parser.add_argument("--collect", action="store_true", help="only gather the finished frames")
    parser.add_argument("--dry-run", action="store_true",
                        help="the simulator stands in for the real runs (the logic, offline)")
    args = parser.parse_args(argv)
    setup = dataclasses.replace(setup, repeats=args.repeats, dry_run=args.dry_run or setup.dry_run)
    if args.collect:
        collect(setup, args.out)
    else:
        validate(setup, args.out, only=args.only, deadline_s=args.deadline_s)
    return 0
