"""The main job on lavapipe: measure, calibrate, validate, report.

1. measure the pass library and copies one simulated GPU at a time (`mgpusim measure` sweeps);
2. calibrate a profile of this machine from those tables (`mgpusim calibrate`);
3. run 2-GPU sort-first and sort-last for real and in the model (`mgpusim validate`), and, with
   `held_out=True`, further configurations that the calibration never saw (other GPU counts,
   resolutions, iteration and triangle counts);
4. write report.md with the error table, the fit, the timelines and the Perfetto traces.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pandas as pd

from . import steady_window as sw
from .experiment import Experiment, load_experiment
from .output import write_json, write_measured, write_table
from .validate import error_stats, error_table

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments" / "lavapipe"

#: (pass, sweeps): sizes that bracket the validation runs, one GPU at a time.
SWEEPS: list[tuple[str, dict[str, list[Any]]]] = [
    ("fragment_loop", {"width": [128, 256], "height": [96, 192], "iterations": [250, 1000, 4000]}),
    ("mesh", {"width": [128, 256], "height": [96, 192], "triangles": [2000, 10000, 40000]}),
    # composites up to 512x384 too: at the validation sizes they last 0.1-0.7 ms, too short
    # beside a submission's CPU time (~0.1-0.4 ms) to fit the cores they keep busy
    ("composite_sort_first", {"width": [128, 256, 512], "height": [96, 192, 384], "inputs": [1, 3]}),
    ("composite_sort_last", {"width": [128, 256, 512], "height": [96, 192, 384], "inputs": [1, 3]}),
    ("copy_d2h", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("copy_h2d", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("copy_d2d", {"bytes": [16384, 131072, 1048576], "queue": ["graphics"]}),
    ("host_copy", {"bytes": [65536, 262144, 1048576, 4194304], "threads": [1, 2]}),
]

#: Rounds over all SWEEPS, REPS repetitions of each configuration per round: a round takes
#: about 20 s, so the repetitions of one configuration are spread over the machine's phases.
ROUNDS, REPS = 3, 4


#: Untimed frames before each measured run. lavapipe's mesh passes get faster over their first
#: ~10 frames (measured: 2.2 ms falling to 1.5 ms at 5k triangles), so the runner's default of
#: 2 left that trend inside the timed frames.
PREWARM_FRAMES = 12

#: Timed frames of one measured run at most (the runner keeps a trace row per task).
MAX_FRAMES = 2000

#: Overrides of the scene's one pass (dotted keys index the array of passes).
IT, TRI = "scene.passes.0.iterations", "scene.passes.0.triangles"


@dataclass(frozen=True)
class Config:
    name: str
    experiment: str
    overrides: dict[str, Any]


#: Measured runs the calibration may look at: 1-GPU runs (pass costs as the runner records
#: them), 2- and 3-GPU runs (the host effects).
CALIBRATION = [
    Config("sf_1gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 1}),
    Config("sf_1gpu_128x96_it500", "sort_first.toml", {"schedule.gpus": 1, "scene.width": 128,
                                                       "scene.height": 96, IT: 500}),
    Config("sl_1gpu_256x192_t20k", "sort_last.toml", {"schedule.gpus": 1}),
    Config("sl_1gpu_256x192_t5k", "sort_last.toml", {"schedule.gpus": 1, TRI: 5000}),
    Config("sl_1gpu_256x192_t10k", "sort_last.toml", {"schedule.gpus": 1, TRI: 10000}),
    Config("sf_1gpu_320x240_it4000", "sort_first.toml", {"schedule.gpus": 1, "scene.width": 320,
                                                         "scene.height": 240, IT: 4000}),
    Config("sl_1gpu_128x96_t5k", "sort_last.toml", {"schedule.gpus": 1, "scene.width": 128,
                                                    "scene.height": 96, TRI: 5000}),
    Config("sl_1gpu_320x240_t40k", "sort_last.toml", {"schedule.gpus": 1, "scene.width": 320,
                                                      "scene.height": 240, TRI: 40000}),
    Config("sort_first_2gpu", "sort_first.toml", {}),
    Config("sort_last_2gpu", "sort_last.toml", {}),
    Config("sf_2gpu_128x96_it2000", "sort_first.toml", {"scene.width": 128, "scene.height": 96}),
    Config("sl_2gpu_256x192_t10k", "sort_last.toml", {TRI: 10000}),
    # 3 GPUs oversubscribe the two cores 3x: the host effects are fitted there too
    Config("sf_3gpu_128x96_it2000", "sort_first.toml", {"schedule.gpus": 3, "scene.width": 128,
                                                        "scene.height": 96}),
    Config("sl_3gpu_256x192_t10k", "sort_last.toml", {"schedule.gpus": 3, TRI: 10000}),
]
#: Never seen by the calibration: 4 GPUs, 3 GPUs at loads the calibration did not run, other
#: resolutions and loads, the shared-host variant.
HELD_OUT = [
    Config("sf_3gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 3}),
    Config("sf_4gpu_256x192_it2000", "sort_first.toml", {"schedule.gpus": 4}),
    Config("sf_2gpu_320x240_it1000", "sort_first.toml", {"scene.width": 320, "scene.height": 240,
                                                         IT: 1000}),
    Config("sf_2gpu_128x96_it6000", "sort_first.toml", {"scene.width": 128, "scene.height": 96,
                                                        IT: 6000}),
    Config("sf_2gpu_shared_host", "sort_first.toml", {"schedule.host_copy": False}),
    Config("sl_3gpu_256x192_t20k", "sort_last.toml", {"schedule.gpus": 3}),
    Config("sl_4gpu_256x192_t20k", "sort_last.toml", {"schedule.gpus": 4}),
    Config("sl_2gpu_320x240_t60k", "sort_last.toml", {"scene.width": 320, "scene.height": 240,
                                                      TRI: 60000}),
    Config("sl_2gpu_128x96_t5k", "sort_last.toml", {"scene.width": 128, "scene.height": 96,
                                                    TRI: 5000}),
    Config("sl_2gpu_shared_host", "sort_last.toml", {"schedule.host_copy": False}),
]
MAIN_CONFIGS = [c for c in CALIBRATION if c.name in ("sort_first_2gpu", "sort_last_2gpu")]


def measure_all(out: Path, progress: Callable[[str], None]) -> list[Path]:
    """Run every sweep on lavapipe, one simulated GPU, in ROUNDS rounds; write one table
    (+ machine record) per pass. Each row has the pass's time and the process's CPU time while
    it ran, from which `calibrate` fits the cores each pass kind keeps busy."""
    from .vulkan import measure as m  # noqa: PLC0415 - Vulkan only when measuring
    from .vulkan.machine import close_gpus, machine_record, make_gpus  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    gpus = make_gpus(1)
    tables: dict[str, list[pd.DataFrame]] = {name: [] for name, _ in SWEEPS}
    paths = []
    try:
        for r in range(ROUNDS):
            for name, sweeps in SWEEPS:
                progress(f"measure {name} (round {r + 1}/{ROUNDS})")
                df = m.measure(name, gpus, sweeps, reps=REPS, warmup=2)
                tables[name].append(df.assign(repetition=df["repetition"] + r * REPS))
        for name, sweeps in SWEEPS:
            path = out / f"{name}.csv"
            m.write_table(pd.concat(tables[name], ignore_index=True), str(path))
            record = machine_record(gpus, {
                "pass": name, "sweeps": sweeps, "rounds": ROUNDS, "reps": REPS, "warmup": 2,
                "command": "mgpusim main (mgpusim/mainjob.py SWEEPS)"})
            write_json(record, path.with_name(path.name + ".machine.json"))
            paths.append(path)
    finally:
        close_gpus(gpus)
    return paths


def experiment_for(config: Config, profile: Path) -> Experiment:
    """The config's experiment with its overrides (dotted keys, as `--set` takes them)."""
    return load_experiment(EXPERIMENTS / config.experiment, config.overrides, profile=profile)


def with_run_length(configs: list[Config], profile: Path, seconds: float) -> list[Config]:
    """Each configuration with enough frames that its timed part lasts about `seconds` (as the
    model, calibrated on microbenchmarks, predicts it; at least the experiment's own frames).

    Why: this shared machine delivers between one and two cores in phases of 0.25-2 s under
    sustained load (two busy processes each alternate between full and half speed, and no steal
    time is reported), so a run of 0.1 s lands in one phase and repeats of it differ by up to 2x;
    a run of a few seconds averages over the phases."""
    from .simulate import simulate  # noqa: PLC0415 - keeps the module's import light

    out = []
    for config in configs:
        exp = experiment_for(config, profile)
        frame_ms = float(simulate(exp).summary["frame_time_ms"])
        frames = max(exp.schedule.frames,
                     exp.schedule.warmup_frames + math.ceil(seconds * 1e3 / max(frame_ms, 1e-3)))
        out.append(Config(config.name, config.experiment,
                          {**config.overrides, "schedule.frames": min(frames, MAX_FRAMES)}))
    return out


def measure_configs(configs: list[Config], profile: Path, out: Path, repeats: int,
                    progress: Callable[[str], None]) -> dict[str, Path]:
    """Run every configuration `repeats` times, interleaved (so a slow phase of a noisy machine
    hits different configurations each round); keep every run; return, per configuration, the
    folder of its steady window (`steady_window`: a fast window of the runs' frames, since
    interference from outside only ever adds time). The spread of the whole runs' frame times
    is reported beside the errors."""
    from .runner.run import run_experiment  # noqa: PLC0415 - Vulkan only when measuring

    exps = {c.name: experiment_for(c, profile) for c in configs}
    runs: dict[str, list[tuple[str, Any]]] = {c.name: [] for c in configs}
    for rep in range(repeats):
        for config in configs:
            progress(f"run {config.name} ({rep + 1}/{repeats})")
            result = run_experiment(exps[config.name], prewarm_frames=PREWARM_FRAMES)
            write_measured(result, out / config.name / f"run{rep}")
            runs[config.name].append((f"run{rep}", result))
    return {c.name: write_steady_window(exps[c.name], runs[c.name], out / c.name)
            for c in configs}


def write_steady_window(exp: Experiment, runs: list[tuple[str, Any]], out: Path) -> Path:
    """Pick the steady window over `runs` ((name, RunResult) of one configuration), write it as
    a measured folder `out/steady`, and the runs' frame times and the choice to
    `out/runs.json`."""
    warmup = exp.schedule.warmup_frames
    candidates = [w for i, (_, r) in enumerate(runs) for w in sw.windows(r.frames, warmup, i)]
    window = sw.pick(candidates)
    name, chosen = runs[window.run]
    steady = out / "steady"
    steady.mkdir(parents=True, exist_ok=True)
    write_table(sw.window_trace(chosen.trace, window, warmup), steady / "trace.csv")
    choice = {"policy": f"window at quantile {sw.QUANTILE} of frame time, windows of at least "
                        f"{sw.WINDOW_MS:g} ms and {sw.MIN_PERIODS} frame periods",
              "run": name, "frames": [window.first, window.last],
              "frames_renumbered_from": window.first - warmup,
              "window_frame_time_ms": window.frame_time_ms, "windows": len(candidates)}
    write_json({"config": chosen.config, "steady_window": choice}, steady / "summary.json")
    write_json(chosen.machine, steady / "machine.json")
    whole = [float(r.summary["frame_time_ms"]) for _, r in runs]
    write_json({"frame_time_ms": whole, **choice}, out / "runs.json")
    return steady


def load_runs(configs: list[Config], chosen: dict[str, Path], profile: Path) -> list[tuple[Any, pd.DataFrame]]:
    from .commands.validate import read_measured  # noqa: PLC0415
    return [(exp, read_measured(chosen[c.name], exp))
            for c in configs for exp in [experiment_for(c, profile)]]


def validate_saved(configs: list[Config], chosen: dict[str, Path], profile: Path, out: Path,
                   progress: Callable[[str], None]) -> pd.DataFrame:
    """Compare each configuration's steady window with the model (no device needed)."""
    from .commands.validate import format_report, validate_experiment  # noqa: PLC0415

    rows = []
    for config in configs:
        exp = experiment_for(config, profile)
        report = validate_experiment(exp, out / config.name, chosen[config.name])
        report["config"] = config.name
        spread = json.loads((chosen[config.name].parent / "runs.json").read_text())["frame_time_ms"]
        report["measured_spread"] = float(max(spread) / min(spread) - 1) if min(spread) > 0 else float("nan")
        progress(format_report(exp, report))
        rows.append(report)
    table = error_table(rows)
    table["run_to_run_spread"] = [r["measured_spread"] for r in rows]
    return table


def write_report(out: Path, tables: dict[str, pd.DataFrame], fit_text: str) -> Path:
    """report.md: per set (calibration runs, held-out runs) the error table and its statistics."""
    lines = ["# mgpusim main job: measured vs simulated on lavapipe", "",
             "Errors are simulated / measured - 1. Measured: the steady window of the repeated, "
             "interleaved runs of each configuration (the window of >= 200 ms at the 10th "
             "percentile of frame time over all runs; outside interference only adds time); "
             "`spread` is (slowest / fastest - 1) of the whole runs' frame times, the machine's own "
             "noise. Each configuration's "
             "folder under validation/ holds `timelines.png` (measured above simulated) and both "
             "Perfetto traces.", ""]
    stats = {}
    for title, table in tables.items():
        if table.empty:
            continue
        st = stats[title] = error_stats(table)
        lines += [f"## {title}", "", _markdown(table), "",
                  f"Median |frame-time error| {st['median_abs_frame_time_error']:.1%}, worst "
                  f"{st['worst_abs_frame_time_error']:.1%} over {st['configurations']} configurations; "
                  f"median |latency error| {st['median_abs_latency_error']:.1%}.", ""]
        table.to_csv(out / f"errors_{title.split()[0].lower()}.csv", index=False)
    lines += ["## Calibration", "", "```", fit_text, "```", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    write_json(stats, out / "errors.json")
    return path


def _markdown(table: pd.DataFrame) -> str:
    head = ("| config | measured frame (ms) | simulated | error | spread | measured latency (ms) | "
            "simulated | error |")
    rows = [head, "|---|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        rows.append(f"| {r.config} | {r.measured_frame_ms:.2f} | {r.simulated_frame_ms:.2f} | "
                    f"{r.frame_time_error:+.1%} | {r.run_to_run_spread:.0%} | {r.measured_latency_ms:.2f} | "
                    f"{r.simulated_latency_ms:.2f} | {r.latency_error:+.1%} |")
    return "\n".join(rows)
