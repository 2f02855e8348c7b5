"""The speeds a user feels, in one place (`mgpusim bench --what figures`): sweep points per
second (analytic, over pass-cost lanes and over scene keys alone, and full fidelity with the
fast-forward), the start-up of `mgpusim --version`,
one `simulate()` call of the shipped sort-first experiments (the experiment loaded once, and
loaded afresh each call), AFR's cost over its GPU count with the fast-forward and, behind a
flag, `mgpusim advise` on the 20-pass frame (:mod:`.advise_frame`).

Why every figure comes with its ratio to the reference loop (:func:`.reference.reference_loop`,
timed before and after, the faster kept): the development machine is shared and its speed
moves 10-130 % within minutes, so a time alone says little across runs; a time divided by the
loop's (`reference_loops`), or a rate times it (`per_reference_loop`), does. Each figure is
``{"value": number, "unit": text, "reference_ratio": number}``.
"""
from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from mgpusim.bench.reference import reference_loop

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "experiments"
#: The sort-first experiments whose simulate() call is timed (TC1, and lavapipe's shared cores).
SORT_FIRST = {"sort_first_tc1": EXPERIMENTS / "sort_first_tc1.toml",
              "lavapipe_sort_first": EXPERIMENTS / "lavapipe" / "sort_first.toml"}
#: Pass-cost lane values (10 each) over 10 widths: 10^5 points of TC1 sort-first.
_WIDTHS = "scene.width=640,800,960,1024,1280,1440,1600,1920,2560,3840"
_LANE_KEYS = ["profile.gpus.*.speed=0.5,0.75,1,1.25,1.5,2,2.5,3,4,5",
              "profile.gpus.*.costs.fragment_loop.ns_per_pixel_iteration="
              "0.0008,0.001,0.0012,0.0014,0.0016,0.0018,0.002,0.0024,0.003,0.004",
              "profile.gpus.*.costs.fragment_loop.fixed_ns=0,5000,10000,20000,30000,40000,50000,60000,80000,100000",
              "profile.gpus.*.costs.composite_sort_first.fixed_ns=0,2500,5000,10000,15000,20000,30000,40000,60000,80000"]
#: The sweeps timed: name -> (experiment, grid arguments, other arguments). Grids as large as
#: a user's (10^3-10^5 points), so that a sweep's fixed cost (about 1 s: imports, the table)
#: counts as it does for them.
SWEEPS: dict[str, tuple[Path, list[str], list[str]]] = {
    # 10 widths (groups) x 10^4 pass-cost combinations (lanes)
    "analytic": (SORT_FIRST["sort_first_tc1"], [_WIDTHS, *_LANE_KEYS], ["--fidelity", "analytic"]),
    # scene and schedule keys alone: every point a program of its own (3 structures)
    "analytic_scene": (SORT_FIRST["sort_first_tc1"],
                       ["scene.width=" + ",".join(str(600 + 8 * i) for i in range(40)),
                        "scene.height=" + ",".join(str(400 + 6 * i) for i in range(25)), "schedule.gpus=1,2,3"],
                       ["--fidelity", "analytic"]),
    # full fidelity with the fast-forward: 1,000 frames, the state repeats from frame 92
    "full": (SORT_FIRST["sort_first_tc1"],
             ["profile.gpus.*.speed=" + ",".join(f"{0.5 + 0.1 * i:g}" for i in range(10)),
              "scene.width=" + ",".join(str(700 + 10 * i) for i in range(40))],
             ["--set", "schedule.frames=1000"]),
    # full fidelity, AFR on one GPU, 10,000 frames (repeats from frame 1): a point's set-up
    "full_afr": (EXPERIMENTS / "afr_tc1.toml",
                 ["profile.gpus.*.speed=" + ",".join(f"{0.5 + 0.01 * i:g}" for i in range(100)),
                  "scene.width=" + ",".join(str(700 + 10 * i) for i in range(40))],
                 ["--set", "schedule.gpus=1", "--set", "schedule.frames=10000"]),
}
AFR_GPUS = (1, 2, 4, 8)
AFR_FRAMES = 1000
Step = Callable[[str], None]


def figure(value: float, unit: str, ref: float, rate: bool = False) -> dict[str, Any]:
    """One figure: a time (s) is divided by the reference loop's, a rate (per s) multiplied."""
    return {"value": value, "unit": unit, "reference_ratio": value * ref if rate else value / ref}


def figures(advise: bool = False, step: Step | None = None) -> dict[str, Any]:
    """Every figure (see the module doc), with the reference loop's CPU seconds."""
    say = step or (lambda _name: None)
    refs = [min(reference_loop() for _ in range(3))]
    raw: dict[str, Any] = {}
    say("sweeps")
    raw["sweep"] = {name: sweep_points_per_s(*spec) for name, spec in SWEEPS.items()}
    say("start-up")
    raw["startup"] = startup_s()
    say("simulate() calls")
    raw["simulate_call"] = {name: simulate_call_s(path) for name, path in SORT_FIRST.items()}
    say("AFR with the fast-forward")
    afr_cpu_s(1, 100)  # (imports, caches)
    raw["afr_fast_forward"] = {f"{n}_gpus": afr_cpu_s(n) for n in AFR_GPUS}
    if advise:
        say("advise, 20 passes")
        raw["advise_20_passes"] = advise_s()
    refs.append(min(reference_loop() for _ in range(3)))
    ref = min(refs)
    return {"reference_loop_s": ref, "reference_loop_slowest_s": max(refs), "cpus": os.cpu_count(),
            **_with_ratios(raw, ref)}


def _with_ratios(raw: dict[str, Any], ref: float) -> dict[str, Any]:
    """Each (value, unit) leaf of `raw` as a figure (units ending in '/s' are rates); a count
    (an int: points, processes) is kept as it is."""
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if isinstance(value, dict):
            out[key] = _with_ratios(value, ref)
        elif isinstance(value, tuple):
            number, unit = value
            out[key] = figure(float(number), unit, ref, rate=unit.endswith("/s"))
        else:
            out[key] = value
    return out


def sweep_points_per_s(experiment: Path, grid: list[str], extra: list[str]) -> dict[str, Any]:
    """Points per second of a whole `mgpusim sweep` command in a fresh process (wall), with its
    points and its CPU seconds (the command's and its workers')."""
    with tempfile.TemporaryDirectory() as tmp:
        args = [sys.executable, "-m", "mgpusim", "sweep", str(experiment), "--no-progress",
                "--out", str(Path(tmp) / "sweep"), *extra]
        for item in grid:
            args += ["--grid", item]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(args, check=True, capture_output=True, env=_env(), cwd=ROOT)  # (-m: cwd first on the path)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    points = 1
    for item in grid:
        points *= len(item.partition("=")[2].split(","))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"points_per_s": (points / wall, "points/s"), "wall_s": (wall, "s"), "cpu_s": (cpu, "s"),
            "points": points}


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def startup_s(runs: int = 7) -> dict[str, tuple[float, str]]:
    """Median wall seconds of `mgpusim --version` and of a bare interpreter, interleaved."""
    times: dict[str, list[float]] = {"version_s": [], "bare_interpreter_s": []}
    cases = {"version_s": ["-m", "mgpusim", "--version"], "bare_interpreter_s": ["-c", "pass"]}
    for k in range(runs + 1):
        for name, argv in cases.items():
            t0 = time.perf_counter()
            subprocess.run([sys.executable, *argv], check=True, stdout=subprocess.DEVNULL, env=_env())
            if k:  # the first run of each is untimed (the file cache, the .pyc files)
                times[name].append(time.perf_counter() - t0)
    return {name: (statistics.median(t), "s") for name, t in times.items()}


def simulate_call_s(path: Path, repeat: int = 15) -> dict[str, tuple[float, str]]:
    """The fastest CPU seconds of one `simulate()` at the analytic level and at full fidelity
    (summary read), the experiment loaded once beforehand (`*_s`) and loaded afresh in each
    call (`*_fresh_load_s`: load_experiment hands back what it loaded while the files are
    unchanged)."""
    from mgpusim import load_experiment, simulate  # noqa: PLC0415

    def best(call: Callable[[], Any]) -> float:
        call()  # (imports, caches)
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            call()
            times.append(time.process_time() - t0)
        return min(times)
    out: dict[str, tuple[float, str]] = {}
    exp = load_experiment(path)
    for fidelity in ("analytic", "full"):
        out[f"{fidelity}_s"] = (best(lambda: simulate(exp, fidelity=fidelity).summary), "s")  # noqa: B023
        out[f"{fidelity}_fresh_load_s"] = (best(lambda: simulate(load_experiment(path), fidelity=fidelity)  # noqa: B023
                                                .summary), "s")
    return out


def afr_cpu_s(gpus: int, frames: int = AFR_FRAMES) -> tuple[float, str]:
    """CPU seconds of one full-fidelity `simulate()` (fast-forward on, summary read) of TC1 AFR
    on `gpus` GPUs with as many frames in flight (benchmarks/afr_fastforward.py, at 10^3 frames)."""
    from mgpusim import load_experiment, simulate  # noqa: PLC0415
    exp = load_experiment(EXPERIMENTS / "afr_tc1.toml", {
        "schedule.gpus": gpus, "profile.gpu_count": max(gpus, 3), "schedule.frames_in_flight": gpus,
        "schedule.frames": frames})
    t0 = time.process_time()
    simulate(exp, record_trace=False).summary  # noqa: B018
    return time.process_time() - t0, "s"


def advise_s(workers: int = 2) -> dict[str, Any]:
    """Wall seconds of `mgpusim advise` on the 20-pass frame, report included, in a fresh process."""
    from mgpusim.bench.advise_frame import frame20_csv  # noqa: PLC0415
    with tempfile.TemporaryDirectory() as tmp:
        csv, exp = Path(tmp) / "frame20.csv", Path(tmp) / "frame20.toml"
        csv.write_text(frame20_csv())
        subprocess.run([sys.executable, "-m", "mgpusim", "frame", "import", str(csv), "--size", "2560x1440",
                        "--out", str(exp), "--profile", str(ROOT / "hardware_profiles" / "pcie4_pair.toml")],
                       check=True, capture_output=True, env=_env())
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "mgpusim", "advise", str(exp), "--out", str(Path(tmp) / "advice"),
                        "--workers", str(workers)], check=True, capture_output=True, env=_env())
        return {"wall_s": (time.perf_counter() - t0, "s"), "workers": workers}
