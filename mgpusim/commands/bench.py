"""`mgpusim bench [--frames N] [--json] [--advise]`: model speed against SimPy on this machine:
per simulated frame against a hand-written SimPy model of the same frame, per event and per
resource use against raw SimPy; and the speeds a user feels (`--what figures`: sweeps, start-up,
one simulate() call, AFR with the fast-forward, `--advise`: advise on a 20-pass frame), each
with its ratio to a fixed reference loop timed in the same run (docs/bench.md)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from mgpusim.io.shipped import resolve_experiment
from mgpusim.model.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="simulated frames per second against a hand-written SimPy model of the "
                                     "same frame, cost per event and per resource use vs raw SimPy")
    p.add_argument("--experiment", type=Path, default=Path("sort_first_tc1"),
                   help="a sort-first experiment file or shipped name (its profile's last GPU is repeated "
                        "if it has fewer than 4)")
    p.add_argument("--frames", type=int, default=5000, help="simulated frames per timed run (default: 5000)")
    p.add_argument("--repeats", type=int, default=3, help="best of this many interleaved runs")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument("--what", choices=("all", "simpy", "long", "analytic", "effects", "figures"), default="all",
                   help="simpy: per simulated frame against a hand-written SimPy model, per event and per "
                        "resource use vs raw SimPy; long: a 10^6-frame run with fast-forward "
                        "(wall, peak memory); analytic: configurations/s; effects: time saved by leaving "
                        "unneeded effects out; figures: sweep points/s, start-up, simulate() calls, AFR "
                        "with the fast-forward, each against a reference loop (default: all)")
    p.add_argument("--advise", action="store_true",
                   help="figures: also time `mgpusim advise` on a 20-pass frame (about 10-30 s)")
    p.add_argument("--long-frames", type=int, default=1_000_000, help="frames of the long run")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mgpusim.bench.figures import figures  # noqa: PLC0415
    from mgpusim.bench.model_speed import analytic_speed, effect_costs, effects_saving, long_run, run_bench  # noqa: PLC0415
    if args.frames < 2 or args.repeats < 1:
        raise InputError(f"need --frames >= 2 and --repeats >= 1, got {args.frames} and {args.repeats}")
    from mgpusim.io.progress import bar  # noqa: PLC0415
    experiment = resolve_experiment(args.experiment)
    wanted = {w: args.what in ("all", w) for w in ("simpy", "long", "analytic", "effects", "figures")}
    steps = ((2 * args.repeats + 2) * wanted["simpy"] + wanted["long"] + wanted["analytic"] + 2 * wanted["effects"]
             + (4 + args.advise) * wanted["figures"])
    out: dict = {}
    with bar(steps, "bench", "step", args.progress) as shown:
        def step(name: str) -> None:
            shown.set_postfix_str(name, refresh=False)
            shown.update(1)
        if wanted["simpy"]:
            out["simpy"] = run_bench(experiment, args.frames, args.repeats, lambda s: step(f"simpy: {s}"))
        if wanted["long"]:
            step(f"long run: {args.long_frames:,} frames")
            out["long"] = long_run(experiment, args.long_frames)
        if wanted["analytic"]:
            step("analytic sweep")
            out["analytic"] = analytic_speed(experiment)
        if wanted["effects"]:
            step("effects left out")
            out["effects"] = effects_saving(experiment, repeats=args.repeats)
            step("each needed effect")
            out["effect_costs"] = effect_costs(repeats=args.repeats)
        if wanted["figures"]:
            out["figures"] = figures(args.advise, lambda s: step(f"figures: {s}"))
    if args.json:
        print(json.dumps(out, sort_keys=True))
        return 0
    if "simpy" in out:
        _print_simpy(out["simpy"])
    if "long" in out:
        fig = out["long"]
        print(f"long run: {fig['frames']:,} frames at full fidelity in {fig['simulate_s']:.2f} s "
              f"({fig['process_s']:.2f} s with imports), peak memory {fig['peak_rss_mb']:.0f} MB; "
              f"fast-forward: {fig['fast_forward']['why']}")
        print(f"  then its whole trace ({fig['rows']:,} rows, {fig['trace_mb']:.0f} MB of Parquet), frames and links "
              f"written in {fig['write_s']:.1f} s, peak memory {fig['peak_rss_with_tables_mb']:.0f} MB")
    if "analytic" in out:
        fig = out["analytic"]
        print(f"analytic: {fig['sweep_configurations_per_s']:,.0f} configurations/s in a "
              f"{fig['sweep_configurations']:,}-point sweep ({fig['sweep_s']:.2f} s); "
              f"{fig['simulate_analytic_per_s']:,.0f}/s one at a time through simulate()")
    if "figures" in out:
        _print_figures(out["figures"])
    if "effects" in out:
        fig = out["effects"]
        print(f"effects: {fig['frames']} frames with only the needed effects ({', '.join(fig['needed'])}) "
              f"{fig['needed_s']:.3f} s, with {', '.join(fig['forced_on'])} forced on {fig['forced_s']:.3f} s: "
              f"{fig['saved']:.0%} saved")
        fig = out["effect_costs"]
        print(f"needed effects of {Path(fig['experiment']).name} ({fig['frames']} frames): all {fig['all_s']:.3f} s; "
              + ", ".join(f"without {n} {t:.3f} s" for n, t in fig["without_s"].items()))
    return 0


def _print_simpy(out: dict) -> None:
    print(f"fast-forward off, {out['frames']:,} frames, best of {out['repeats']}; raw SimPy "
          f"(request/timeout/release on a Resource): {out['raw_simpy_uses_per_s']:,.0f} uses/s")
    for key in ("sort_first_2gpu", "sort_first_4gpu"):
        fig = out[key]
        print(f"{key}: {fig['frames_per_s']:,.0f} simulated frames/s; a hand-written SimPy model of the same "
              f"frame (same presents) {fig['hand_written_frames_per_s']:,.0f}/s: the model is "
              f"{fig['speedup_per_frame_vs_hand_written']:.2f}x faster per simulated frame")
        print(f"  per event: {fig['events_per_frame']:.1f} SimPy events per frame to the hand-written "
              f"{fig['hand_written_events_per_frame']:.1f}; {fig['events_per_s']:,.0f} events/s to "
              f"{fig['hand_written_events_per_s']:,.0f}/s: an event costs the model "
              f"{fig['event_cost_vs_hand_written']:.2f}x what it costs the hand-written model, "
              f"{fig['event_cost_vs_raw_simpy']:.2f}x raw SimPy's ({out['raw_simpy_events_per_s']:,.0f} events/s)")
        print(f"  per resource use ({fig['uses_per_frame']} per frame: {fig['task_uses_per_frame']} on queues/threads, "
              f"{fig['link_uses_per_frame']} on links): {fig['uses_per_s']:,.0f}/s, "
              f"{fig['cost_ratio_vs_raw_simpy']:.2f}x raw SimPy's cost (per task, copies counted once: "
              f"{fig['cost_ratio_per_task_vs_raw_simpy']:.2f}x)")


def _print_figures(figs: dict, prefix: str = "") -> None:
    """Each figure on a line: its name, value and ratio to the reference loop."""
    if not prefix:
        print(f"figures (reference loop {figs['reference_loop_s'] * 1e3:.1f} ms CPU, {figs['cpus']} CPUs):")
    for key, value in figs.items():
        if not isinstance(value, dict):
            continue
        if "reference_ratio" not in value:
            _print_figures(value, f"{prefix}{key}.")
            continue
        kind = "per reference loop" if value["unit"].endswith("/s") else "reference loops"
        print(f"  {prefix}{key}: {value['value']:,.6g} {value['unit']} ({value['reference_ratio']:,.4g} {kind})")
