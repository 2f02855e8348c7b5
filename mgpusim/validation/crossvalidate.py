"""One experiment measured (or a saved run) and simulated, compared, and written to a folder.

Used by `mgpusim validate` and by studies. The comparison itself is :mod:`mgpusim.validation.compare`
(pure); this module adds the measuring, the simulation and the files: summary.json, the
simulated and replayed traces, measured-above-simulated timelines and both Perfetto traces.

Two levels, side by side: the *prediction* (the calibrated cost model) and the *replay* (the
model's timeline on the run's own task durations, :mod:`mgpusim.validation.replayed`). Both
model the schedule as it ran: tasks the runner ran on another queue than the schedule's are
moved there first (`queues_as_run` in the report). Where a lavapipe run's speed was probed, a
third: the prediction at that run's own machine speed (`speed`, :func:`normalized`).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from mgpusim.io.perfetto import chrome_trace_json
from mgpusim.io.plot import comparison_png
from mgpusim.io.writers import frame_window, write_json, write_table, write_text
from mgpusim.measure.repeated_runs import measure_repeated, run_spread
from mgpusim.measure.speed_norm import RunSpeed
from mgpusim.model.speed_scale import at_speed
from mgpusim.results.summary import Result
from mgpusim.results.waits import LONG_WAIT_NS, host_split
from mgpusim.schedules.experiment import Experiment
from mgpusim.schedules.program import build_program
from mgpusim.sim.simulation import simulate
from mgpusim.validation.compare import compare
from mgpusim.validation.measured import other_machine, queues_as_run, read_measured, read_submissions, run_machine
from mgpusim.validation.replayed import replay_comparison

#: The report lists the hand-offs whose mean wait differs by at least this much (ms), at most
#: this many: the ones that explain a frame-time error, not every task.
SHOWN_WAIT_MS = 0.05
SHOWN_WAITS = 3
#: What a comparison draws besides its numbers (left out with `figures=False`).
FIGURES = ("timelines.png", "measured.perfetto.json", "simulated.perfetto.json")


def validate_experiment(exp: Experiment, out: Path, measured_dir: Path | None = None,
                        repeats: int = 3, run_seconds: float = 1.0,
                        speed: RunSpeed | None = None, figures: bool = True) -> dict[str, Any]:
    """Measure (or load) and simulate `exp`; write the comparison to `out`; return its summary.

    Measuring runs the experiment `repeats` times, each about `run_seconds` long, under
    `out/measured/` and compares their steady window (:mod:`mgpusim.measure.steady_window`); the
    report's `measured_spread` is how far the whole runs differed. With the compared run's
    `speed` (a lavapipe study's probes) the report also has the prediction at that run's own
    machine speed under `speed` (:mod:`mgpusim.measure.speed_norm`). Without `figures` the
    timelines and Perfetto traces are left out: the tables alone, in a fifth of the time."""
    if measured_dir is None:
        measured_dir = measure_repeated(exp, out / "measured", repeats, run_seconds)
    measured = read_measured(measured_dir, exp)
    report, sim, replayed = both_levels(exp, measured)
    if speed is not None:
        report["speed"] = normalized(exp, measured, speed)
    report["measured_spread"], report["measured_runs"] = run_spread(measured_dir)
    report["measured_from"] = str(measured_dir)
    elsewhere = other_machine(exp.profile, run_machine(measured_dir))
    if elsewhere is not None:
        report["profile_machine"] = elsewhere
    submissions = read_submissions(measured_dir)
    if submissions is not None:
        report["measured_host_split"] = host_split(measured, submissions, exp.schedule.warmup_frames)
    out.mkdir(parents=True, exist_ok=True)
    write_json(report, out / "summary.json")
    write_table(sim.trace, out / "simulated_trace.parquet")
    write_table(replayed, out / "replayed_trace.parquet")
    if figures:
        _figures(exp, measured, sim, out)
    else:  # an earlier run's figures would show beside these numbers
        for name in FIGURES:
            (out / name).unlink(missing_ok=True)
    return report


def _figures(exp: Experiment, measured: pd.DataFrame, sim: Result, out: Path) -> None:
    """The comparison's timelines (measured above simulated) and both Perfetto traces."""
    title = f"{exp.schedule.name}, {exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}"
    comparison_png(measured, sim.trace, out / "timelines.png", title, sim_links=sim.links)
    write_text(chrome_trace_json(*frame_window(measured, None), f"measured {title}"),
               out / "measured.perfetto.json")
    write_text(chrome_trace_json(*frame_window(sim.trace, sim.links), f"simulated {title}"),
               out / "simulated.perfetto.json")


def both_levels(exp: Experiment, measured: pd.DataFrame) -> tuple[dict[str, Any], Result, pd.DataFrame]:
    """The prediction's comparison with the replay's beside it, both on the schedule as the
    run ran it (`queues_as_run`); the simulated result and the replayed trace."""
    queues = queues_as_run(measured, build_program(exp))
    sim = simulate(exp, queues=queues)
    report = compare(measured, sim.trace, exp.schedule.warmup_frames)
    report["config"] = {**sim.config, "overrides_from": exp.file}  # simulate's own run_config
    report["queues_as_run"] = {str(a): str(b) for a, b in queues.items()}
    report["replay"], replayed = replay_comparison(exp, measured, queues)
    report["replay_frame_time_error"] = report["replay"]["frame_time_error"]
    report["replay_latency_error"] = report["replay"]["latency_error"]
    return report, sim, replayed


def normalized(exp: Experiment, measured: pd.DataFrame, speed: RunSpeed) -> dict[str, Any]:
    """The prediction at the run's own speed, compared with the run, and the run's speed record:
    what summary.json keeps under `speed`."""
    scaled = replace(exp, profile=at_speed(exp.profile, speed.ratio))
    sim = simulate(scaled, queues=queues_as_run(measured, build_program(scaled)))
    report = compare(measured, sim.trace, exp.schedule.warmup_frames)
    return {"run": speed.run, "probe_before_ms": speed.before_ms, "probe_after_ms": speed.after_ms,
            "reference_ms": speed.reference_ms, "probe_ratio": speed.ratio,
            "probe_disagreement": speed.disagreement, "other_cores": speed.other_cores,
            "steal_cores": speed.steal_cores, "flag": speed.flag(),
            "simulated_frame_ms": report["simulated"]["frame_time_ms"],
            "frame_time_error": report["frame_time_error"],
            "simulated_latency_ms": report["simulated"]["latency_ms"],
            "latency_error": report["latency_error"]}


def format_report(exp: Experiment, r: dict[str, Any]) -> str:
    """The comparison as a small text table: frame time, latency, every step."""
    m, s = r["measured"], r["simulated"]
    lines = [f"{exp.name}: {exp.schedule.name}, {exp.schedule.gpus} GPU(s), {exp.scene.width}x{exp.scene.height}",
             f"  {'':12} {'measured':>10} {'simulated':>10} {'error':>8}",
             f"  {'frame (ms)':12} {m['frame_time_ms']:10.3f} {s['frame_time_ms']:10.3f} {r['frame_time_error']:+8.1%}",
             f"  {'latency (ms)':12} {m['latency_ms']:10.3f} {s['latency_ms']:10.3f} {r['latency_error']:+8.1%}"]
    if "replay" in r:  # the timeline alone: the model on the run's own task durations
        p = r["replay"]["simulated"]
        lines += [f"  {'replay frame':12} {m['frame_time_ms']:10.3f} {p['frame_time_ms']:10.3f} "
                  f"{r['replay_frame_time_error']:+8.1%}",
                  f"  {'replay lat.':12} {m['latency_ms']:10.3f} {p['latency_ms']:10.3f} "
                  f"{r['replay_latency_error']:+8.1%}"]
    for queue, ran_on in r.get("queues_as_run", {}).items():
        lines.append(f"  modelled as run: {queue}'s tasks on {ran_on} (the runner opens one queue per family)")
    for step, v in r["steps"].items():
        lines.append(f"  {step:12} {v['measured_ms']:10.3f} {v['simulated_ms']:10.3f} {v['error']:+8.1%}")
    waits = [(edge, w) for edge, w in r.get("waits", {}).items()
             if abs(w["difference_ms"]) >= SHOWN_WAIT_MS][:SHOWN_WAITS]
    if waits:
        lines.append("  waits from ready to start, mean (ms), where they differ most:")
        split = r.get("measured_host_split", {})
        for edge, w in waits:
            lines.append(f"    {edge}: {w['measured_ms']:.3f} measured ({w['measured_long_share']:.0%} "
                         f"over {LONG_WAIT_NS / 1e6:g} ms), {w['simulated_ms']:.3f} simulated")
            if edge in split:  # where the measured wait went, at the submit thread
                h = split[edge]
                lines.append(f"      measured: inputs seen after {h['input_seen_ms']:.3f}, submit "
                             f"called {h['submit_call_ms']:.3f} later, started {h['device_start_ms']:.3f} later")
    elsewhere = r.get("profile_machine")
    if elsewhere:
        said = "; ".join(f"{k} {elsewhere['profile'][k]!r}, the run's {elsewhere['run'][k]!r}"
                         for k in elsewhere["differs"])
        lines.append(f"  note: the profile was calibrated on another machine ({said}); its accuracy "
                     "holds there: calibrate one on this machine (bash scripts/main.sh on lavapipe)")
    sp = r.get("speed")
    if sp:  # the prediction at the run's own machine speed
        lines.append(f"  normalized at probe ratio {sp['probe_ratio']:.2f}: frame "
                     f"{sp['simulated_frame_ms']:.3f} ms {sp['frame_time_error']:+.1%}, latency "
                     f"{sp['latency_error']:+.1%}" + (f" (flagged: {sp['flag']})" if sp["flag"] else ""))
    stalled = r.get("stalls", {}).get("frames", {})
    if stalled:
        shown = ", ".join(f"{f} ({ms:.1f} ms)" for f, ms in list(stalled.items())[:5])
        lines.append(f"  measured: {len(stalled)} stalled frame(s) over {r['stalls']['factor']:g}x the "
                     f"mean of the other frames, left out: {shown}{' ...' if len(stalled) > 5 else ''}")
    if r.get("measured_runs", 1) > 1:
        lines.append(f"  measured: steady window of {r['measured_runs']} runs; the whole runs' frame "
                     f"times spread {r['measured_spread']:.1%} (the machine's own noise)")
    return "\n".join(lines)
