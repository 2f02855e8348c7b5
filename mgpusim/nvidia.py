"""The NVIDIA validation (issue 5): configurations run for real on the two H200s, re-validated offline.

Why a module: the device script (`data/nvidia/run_h200x2.sh`) and the offline validation read the
same list (`experiments/h200/configs.toml`; calibration runs: `calibration.toml`), so a saved
run folder `data/nvidia/h200x2/runs_si/<name>/` always meets the experiment it was measured with.

    python -m mgpusim.nvidia run OUT [--configs F] [--devices 0,1] [--budget S]   # on the device
    python -m mgpusim.nvidia validate [--measured ROOT] [--profile P] [--out DIR]   # offline
    python -m mgpusim.nvidia calibrate-h200 [--runs DIR] | calibrate-h100            # the profiles

See docs/nvidia.md for the results.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "experiments" / "h200" / "configs.toml"
CALIBRATION = ROOT / "experiments" / "h200" / "calibration.toml"
MEASURED = ROOT / "data" / "nvidia" / "h200x2" / "runs_si"
PROFILE = ROOT / "hardware_profiles" / "h200_x2.toml"


@dataclass(frozen=True)
class NvConfig:
    name: str
    experiment: Path
    sets: tuple[str, ...]


def load_configs(path: Path = CONFIGS) -> list[NvConfig]:
    data = tomllib.loads(path.read_text())
    return [NvConfig(c["name"], path.parent / c["experiment"], tuple(c.get("set", ())))
            for c in data["config"]]


def experiment_for(config: NvConfig, profile: Path | str | None = None, extra: list[str] | None = None):
    from .experiment import load_experiment, parse_overrides  # noqa: PLC0415
    return load_experiment(config.experiment, parse_overrides([*config.sets, *(extra or [])]),
                           profile=str(profile) if profile else None)


def run_all(out: Path, devices: str = "0,1", budget_s: float = 300, timeout_s: float = 90,
            configs: Path = CONFIGS, only: str | None = None) -> None:
    """Every configuration with `mgpusim run --devices`, one subprocess each, until the budget."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    for c in load_configs(configs):
        if only and only not in c.name:
            continue
        left = budget_s - (time.monotonic() - t0)
        if left < 15:
            print(f"SKIP (time) {c.name}", flush=True)
            continue
        gpus = experiment_for(c).schedule.gpus
        cmd = [sys.executable, "-m", "mgpusim.cli", "run", str(c.experiment),
               "--devices", ",".join(devices.split(",")[:gpus]),
               *[a for s in c.sets for a in ("--set", s)], "--out", str(out / c.name)]
        s = time.monotonic()
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=min(timeout_s, left - 5))
            rc, text = p.returncode, p.stdout + p.stderr
        except subprocess.TimeoutExpired as exc:
            rc, text = "timeout", str(exc.stdout or "") + str(exc.stderr or "")
        (out / f"{c.name}.log").write_text(text)
        print(f"{c.name} rc={rc} {time.monotonic() - s:.0f}s\n  " + "\n  ".join(text.strip().splitlines()[-3:]),
              flush=True)


def validate_saved(measured_root: Path = MEASURED, profile: Path | str | None = PROFILE,
                   out: Path | None = None, names: list[str] | None = None,
                   extra: list[str] | None = None) -> pd.DataFrame:
    """`validate --measured` for each saved configuration; the error table (one row each)."""
    from .commands.validate import validate_experiment  # noqa: PLC0415
    from .validate import error_table  # noqa: PLC0415
    out = out or ROOT / "out" / "h200_validate"
    rows = []
    for c in load_configs():
        folder = measured_root / c.name
        if (names and c.name not in names) or not folder.is_dir():
            continue
        exp = experiment_for(c, profile, extra)
        report = validate_experiment(exp, out / c.name, folder)
        report["config"] = c.name
        rows.append(report)
    return error_table(rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m mgpusim.nvidia")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--devices", default="0,1")
    r.add_argument("--budget", type=float, default=300)
    r.add_argument("--configs", type=Path, default=CONFIGS)
    r.add_argument("--only", help="run only the configurations whose name contains this")
    v = sub.add_parser("validate")
    v.add_argument("--measured", type=Path, default=MEASURED)
    v.add_argument("--profile", default=str(PROFILE))
    v.add_argument("--out", type=Path, default=ROOT / "out" / "h200_validate")
    v.add_argument("--set", dest="extra", action="append", default=[])
    c = sub.add_parser("calibrate-h200")
    c.add_argument("--out", type=Path, default=PROFILE)
    c.add_argument("--base", type=Path, default=PROFILE)
    c.add_argument("--runs", type=Path, default=MEASURED.parent / "calibration_si",
                   help="calibration runs folder (default: the 0.2 ms switch-interval set)")
    sub.add_parser("calibrate-h100")
    args = p.parse_args(argv)
    if args.cmd == "calibrate-h100":
        print(calibrate_h100())
        return 0
    if args.cmd == "calibrate-h200":
        print(calibrate_h200(args.out, args.base, calibration_runs=args.runs))
        return 0
    if args.cmd == "run":
        run_all(args.out, args.devices, args.budget, configs=args.configs, only=args.only)
        return 0
    from .output import write_json  # noqa: PLC0415
    from .validate import error_stats  # noqa: PLC0415
    table = validate_saved(args.measured, args.profile, args.out, extra=args.extra)
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "errors.csv", index=False)
    stats = error_stats(table)
    write_json(stats, args.out / "errors.json")
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False))
    print(json.dumps(stats, indent=2))
    return 0



# -- calibration -------------------------------------------------------------------------------
H200_TABLES = ("copy_d2h.csv", "copy_h2d.csv", "copy_d2d.csv", "host_copy.csv", "fragment_loop.csv",
               "mesh.csv", "mesh_4320.csv", "composite_sort_first.csv", "composite_sort_last.csv",
               "particle_update.csv", "particle_render.csv")
H100_TABLES = H200_TABLES  # the same measurements were taken on both
#: Pass kinds whose runner form differs from the microbenchmark's (the composite draws into the
#: frame the primary already rendered; present is an image copy in GENERAL layout): fitted on
#: the calibration runs' own rows instead.
RUN_FITTED = ("composite_sort_first", "composite_sort_last", "present")
DISPATCH_GRID_NS = tuple(range(0, 2_000_001, 50_000))


def saved_runs(configs: Path, root: Path, profile: Path | str | None = None) -> list[tuple[Any, pd.DataFrame]]:
    """(experiment, measured trace) for each configuration of `configs` saved under `root`."""
    from .commands.validate import read_measured  # noqa: PLC0415
    runs = []
    for c in load_configs(configs):
        if (root / c.name).is_dir():
            exp = experiment_for(c, profile)
            runs.append((exp, read_measured(root / c.name, exp)))
    return runs


def fit_run_passes(runs, kinds=RUN_FITTED) -> dict[str, Any]:
    """fixed_ns + ns_per_pixel per kind on the steady-state rows of real multi-GPU runs (each
    simulated GPU is its own real GPU, so nothing competes). The input count is the same in
    every run (2 GPUs), so no per-input term is fitted (it is set to 0)."""
    import numpy as np  # noqa: PLC0415
    from .calibrate.fit import fit_nonnegative  # noqa: PLC0415
    from .simulate import build_program  # noqa: PLC0415
    from .tasks import PassTask  # noqa: PLC0415
    rows: dict[str, list[tuple[float, float]]] = {k: [] for k in kinds}
    for exp, trace in runs:
        program = build_program(exp)
        steady = trace[trace["frame"] >= exp.schedule.warmup_frames]
        for task in program.templates[0]:
            if isinstance(task, PassTask) and task.kind in rows:
                d = steady.loc[steady["task"] == task.name]
                rows[task.kind].extend((float(task.work.get("pixel", 0.0)), float(v))
                                       for v in (d["end_ns"] - d["start_ns"]))
    fits = {}
    for kind, samples in rows.items():
        if samples:
            X = np.array([[1.0, px] for px, _ in samples])
            y = np.array([v for _, v in samples])
            fits[kind] = fit_nonnegative(X, y, ["fixed_ns", "ns_per_pixel"], f"{kind} (runs)")
    return fits


def fit_host_copy(table: Path, threads: int) -> tuple[float, float, int]:
    """Host copy on `threads` threads as fixed + bytes / B (the model's parts run in parallel,
    each paying host_copy_fixed_ns): (fixed_ns, B in GB/s, rows)."""
    import numpy as np  # noqa: PLC0415
    from .calibrate.fit import fit_nonnegative  # noqa: PLC0415
    d = pd.read_csv(table)
    d = d[d["threads"] == threads]
    fit = fit_nonnegative(np.c_[np.ones(len(d)), d["bytes"].to_numpy(float)], d["duration_ns"].to_numpy(float),
                          ["fixed_ns", "ns_per_byte"], "host copy")
    return float(fit.coef[0]), 1.0 / float(fit.coef[1]), len(d)


def calibrate_h200(out: Path = PROFILE, base: Path = PROFILE, tables: Path = MEASURED.parent,
                   calibration_runs: Path = MEASURED.parent / "calibration_si") -> str:
    """hardware_profiles/h200_x2.toml from the H200 tables (`mgpusim calibrate --base`), then the
    runner-form pass costs and the host dispatch delay from the calibration runs. Returns the report."""
    import copy  # noqa: PLC0415
    import io  # noqa: PLC0415
    import tempfile  # noqa: PLC0415
    from contextlib import redirect_stderr, redirect_stdout  # noqa: PLC0415

    import tomli_w  # noqa: PLC0415

    from .cli import main as cli  # noqa: PLC0415
    from .profile import parse_profile  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as tmp:
        fitted = Path(tmp) / "h200.toml"
        buf = io.StringIO()
        with redirect_stdout(buf), redirect_stderr(io.StringIO()):
            cli(["calibrate", *[str(tables / t) for t in H200_TABLES], "--base", str(base), "--out", str(fitted)])
        data = tomllib.loads(fitted.read_text())
    lines = ["mgpusim calibrate " + " ".join(H200_TABLES) + " --base " + base.name, buf.getvalue().rstrip(),
             f"calibration runs: {calibration_runs.relative_to(ROOT) if calibration_runs.is_relative_to(ROOT) else calibration_runs}"]
    host = data["host"]
    threads = int(host["memcpy_threads"])
    fixed, gbps, n = fit_host_copy(tables / "host_copy_threads.csv", threads)
    host.update(host_copy_fixed_ns=int(round(fixed)), memory_bandwidth_gbps=round(gbps, 3),
                memcpy_thread_gbps=round(gbps / threads, 4))
    lines.append(f"host copy on {threads} threads (host_copy_threads.csv, {n} rows): "
                 f"{fixed / 1e3:.0f} us + bytes / {gbps:.1f} GB/s")
    probe = parse_profile(copy.deepcopy(data), "<calibration>")
    runs = saved_runs(CALIBRATION, calibration_runs, None)
    runs = [(_with_profile(exp, probe), trace) for exp, trace in runs]
    for kind, fit in fit_run_passes(runs).items():
        for gpu in data["gpus"]:
            gpu["costs"][kind] = {"fixed_ns": float(f"{fit.coef[0]:.6g}"), "ns_per_pixel": float(f"{fit.coef[1]:.6g}")}
            if kind.startswith("composite"):
                gpu["costs"][kind]["ns_per_input"] = 0.0
        lines.append(f"{kind} from calibration runs: fixed_ns={fit.coef[0]:.0f}+-{fit.stderr[0]:.0f}, "
                     f"ns_per_pixel={fit.coef[1]:.5f}+-{fit.stderr[1]:.1e}; rms {fit.rel_rms:.1%} ({len(fit.rel_residuals)} rows)")
    probe = parse_profile(copy.deepcopy(data), "<calibration>")
    runs = [(_with_profile(exp, probe), trace) for exp, trace in runs]
    from .calibrate.runs import fit_host_effects  # noqa: PLC0415
    found, score = fit_host_effects(data, runs, {"dispatch_ns": DISPATCH_GRID_NS})
    host["dispatch_ns"] = found["dispatch_ns"]
    lines.append(f"host dispatch_ns={host['dispatch_ns']} (grid 0..2 ms on {len(runs)} calibration runs; "
                 f"mean |frame-time error| {score:.1%})")
    data["sources"].update(
        host=("32 CPU cores, 256 GiB. memcpy_threads = 8: the host-copy split that the runner and the model "
              "both use (8 Python copy threads were fastest at the schedules' sizes; 32 contend for the GIL, "
              "data/nvidia/h200x2/host_copy.csv). Host copy cost and dispatch_ns: see calibration."),
        gpus=("memory 141 GB HBM3e (public spec). Queue families from `mgpusim devices` (data/nvidia/h200x2/"
              "devices.txt): graphics+compute+transfer x16, transfer-only x2, compute+transfer x8. Costs and "
              "copy rates: see calibration. particle_update/particle_render: measured in the fourth call (run_h200x2_d.sh)."),
        link=("PCIe 5.0 x16 per GPU, rates fitted (calibration). Both GPUs copying at once keep ~the same "
              "rate each (copy_d2h_2gpus.csv, copy_h2d_2gpus.csv): the links are independent. peer_links: "
              "CUDA peer copy over NVLink ~375 GB/s (DOMAIN.md 5), not reachable from Vulkan without device "
              "groups: for what-ifs only."))
    data["sources"]["calibration"] = (
        "pass costs (fragment_loop, mesh), copy rates per queue and path: `mgpusim calibrate "
        + " ".join(H200_TABLES) + " --base h200_x2.toml` on the tables in data/nvidia/h200x2/ (one H200, "
        "driver 580.159.04, 2026-11-22). Host copy on memcpy_threads threads: host_copy_threads.csv. "
        "composite_sort_first/last and present: fitted on the runner's own rows of the calibration runs "
        "(experiments/h200/calibration.toml, data/nvidia/h200x2/calibration_si/: runner with a 0.2 ms GIL switch interval), because the runner's composite "
        "draws into the frame the primary rendered and present is an image copy in GENERAL layout, neither "
        "what the microbenchmarks time. host.dispatch_ns: grid search on the same calibration runs. "
        "The validation runs (configs.toml) are held out. mgpusim.nvidia.calibrate_h200() rebuilds this file.")
    header = "# Calibrated by mgpusim.nvidia.calibrate_h200(). Fit report:\n" + "".join(
        f"#   {line}\n" for text in lines for line in text.splitlines())
    out.write_text(header + "\n" + tomli_w.dumps(data))
    return "\n".join(lines)


def calibrate_h100(out: Path = ROOT / "hardware_profiles" / "h100.toml",
                   base: Path = PROFILE, tables: Path = ROOT / "data" / "nvidia" / "h100") -> str:
    """hardware_profiles/h100.toml: `mgpusim calibrate --base` on the H100 tables with the structure
    of the calibrated H200 profile (one GPU, 80 GB, 16 cores, no peer link); composite, present
    and dispatch_ns are the H200's runner-form fits (same GH100 chip, same runner: no multi-GPU
    H100 machine to run the schedule on)."""
    import io  # noqa: PLC0415
    import tempfile  # noqa: PLC0415
    from contextlib import redirect_stderr, redirect_stdout  # noqa: PLC0415

    import tomli_w  # noqa: PLC0415

    from .cli import main as cli  # noqa: PLC0415
    h200 = tomllib.loads(base.read_text())
    skeleton = {k: v for k, v in h200.items() if k != "peer_links"}
    skeleton.update(name="h100", description="1x NVIDIA H100 80GB HBM3 (PCIe 5.0 x16), driver 580")
    skeleton["host"] = {**h200["host"], "cpu_cores": 16}
    skeleton["gpus"] = [{**h200["gpus"][0], "name": "NVIDIA H100 80GB HBM3", "count": 1,
                         "memory_bytes": 85899345920}]
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "base.toml").write_text(tomli_w.dumps(skeleton))
        fitted = Path(tmp) / "h100.toml"
        buf = io.StringIO()
        with redirect_stdout(buf), redirect_stderr(io.StringIO()):
            cli(["calibrate", *[str(tables / t) for t in H100_TABLES], "--base", str(Path(tmp) / "base.toml"),
                 "--out", str(fitted)])
        data = tomllib.loads(fitted.read_text())
    lines = ["mgpusim calibrate " + " ".join(H100_TABLES) + " --base (h200_x2.toml, one GPU)", buf.getvalue().rstrip()]
    host = data["host"]
    threads = int(host["memcpy_threads"])
    fixed, gbps, n = fit_host_copy(tables / "host_copy.csv", threads)
    host.update(host_copy_fixed_ns=int(round(fixed)), memory_bandwidth_gbps=round(gbps, 3),
                memcpy_thread_gbps=round(gbps / threads, 4), dispatch_ns=int(h200["host"]["dispatch_ns"]))
    lines.append(f"host copy on {threads} threads (host_copy.csv, {n} rows): {fixed / 1e3:.0f} us + bytes / {gbps:.1f} GB/s")
    for kind in RUN_FITTED:
        data["gpus"][0]["costs"][kind] = dict(h200["gpus"][0]["costs"][kind])
    lines.append("composite_sort_first/last, present, dispatch_ns: the H200 profile's (runner-form fits)")
    data["sources"] = {
        "host": "16 CPU cores, 128 GiB (the nvidia-h100-x1 machine). memcpy_threads = 8 as on the H200 machine.",
        "gpus": ("NVIDIA H100 80GB HBM3, driver 580.159.04 (data/nvidia/h100/devices.txt): graphics+compute+"
                 "transfer x16, transfer-only x2, compute x8."),
        "link": "PCIe 5.0 x16; rates fitted (calibration). No peer link (one GPU).",
        "calibration": ("`mgpusim calibrate " + " ".join(H100_TABLES) + " --base <h200_x2.toml with one GPU>` on "
                        "data/nvidia/h100/ (2026-11-22). Host copy on 8 threads: host_copy.csv. composite_sort_first/"
                        "last, present and host.dispatch_ns: copied from h200_x2.toml, whose values were fitted on "
                        "the runner's own rows on the H200s (same GH100 chip; the composite, fragment-loop and copy "
                        "microbenchmarks agree within 1% between H100 and H200). mgpusim.nvidia.calibrate_h100() "
                        "rebuilds this file."),
    }
    header = "# Calibrated by mgpusim.nvidia.calibrate_h100(). Fit report:\n" + "".join(
        f"#   {line}\n" for text in lines for line in text.splitlines())
    out.write_text(header + "\n" + tomli_w.dumps(data))
    return "\n".join(lines)


def nvlink_profiles(profile: Path = PROFILE) -> dict[str, Any]:
    """What-if profiles for the NVLink question. The five-step schedule has no peer-copy route
    (steps 2 and 4 are a d2h and an h2d over each GPU's own link), so the what-if gives each
    GPU's link the peer link's bandwidth and latency (`peer_links[0]`, ~375 GB/s) and drops the
    host step (host_copy = false: the contribution lands in memory the primary reads).
    `nvlink`: that, with the measured host dispatch between the two copies (Vulkan without
    device groups still synchronises the two devices on the host); `nvlink_groups`: also no
    host dispatch (device groups: cross-device semaphores)."""
    import copy  # noqa: PLC0415

    from .profile import parse_profile  # noqa: PLC0415
    data = tomllib.loads(profile.read_text())
    peer = data["peer_links"][0]
    out = {"measured_links": parse_profile(copy.deepcopy(data), str(profile))}
    nv = copy.deepcopy(data)
    for gpu in nv["gpus"]:
        gpu["link"].update(h2d_gbps=peer["bandwidth_gbps"], d2h_gbps=peer["bandwidth_gbps"],
                           latency_ns=peer["latency_ns"])
        for fam in gpu.get("copy", {}).values():
            fam.pop("d2h_gbps", None)
            fam.pop("h2d_gbps", None)
    out["nvlink"] = parse_profile(copy.deepcopy(nv), str(profile) + " (NVLink what-if)")
    nv["host"]["dispatch_ns"] = 0
    out["nvlink_groups"] = parse_profile(nv, str(profile) + " (NVLink + device groups what-if)")
    return out


def nvlink_whatif(profile: Path = PROFILE, extra: list[str] | None = None) -> pd.DataFrame:
    """Simulated frame time and latency of every validation configuration: as run (PCIe, the
    configuration's own host_copy), and over NVLink-rate links (see nvlink_profiles)."""
    from .simulate import simulate  # noqa: PLC0415
    profiles = nvlink_profiles(profile)
    rows = []
    for c in load_configs():
        if experiment_for(c).schedule.gpus < 2:
            continue  # one GPU: nothing crosses
        row: dict[str, Any] = {"config": c.name}
        for label, prof in profiles.items():
            sets = list(extra or []) + ([] if label == "measured_links" else ["schedule.host_copy=false"])
            exp = _with_profile(experiment_for(c, profile, sets), prof)
            s = simulate(exp, record_trace=False).summary
            row[f"{label}_frame_ms"] = s["frame_time_ms"]
            row[f"{label}_latency_ms"] = s["latency_ms"]
        rows.append(row)
    return pd.DataFrame(rows)


def _with_profile(exp, profile):
    from dataclasses import replace  # noqa: PLC0415
    return replace(exp, profile=profile)


def _entry() -> int:
    """`python -m mgpusim.nvidia`: user errors as one line, like the mgpusim command."""
    from .errors import MgpusimError  # noqa: PLC0415
    try:
        return main()
    except MgpusimError as exc:
        print(f"python -m mgpusim.nvidia: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(_entry())
