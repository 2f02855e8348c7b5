"""The NVIDIA validation (issue 5): configurations run for real on the two H200s, re-validated offline.

Why a module: the device script (`data/nvidia/run_h200x2.sh`) and the offline validation read the
same list (`experiments/h200/configs.toml`), so a saved run folder
`data/nvidia/h200x2/runs/<name>/` always meets the experiment it was measured with.

    python -m mgpusim.nvidia run OUT [--devices 0,1] [--budget S]     # on the device machine
    python -m mgpusim.nvidia validate [--measured ROOT] [--profile P] [--out DIR]   # offline
"""
from __future__ import annotations

import argparse
import json
import os
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
MEASURED = ROOT / "data" / "nvidia" / "h200x2" / "runs"
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


def run_all(out: Path, devices: str = "0,1", budget_s: float = 300, timeout_s: float = 90) -> None:
    """Every configuration with `mgpusim run --devices`, one subprocess each, until the budget."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    for c in load_configs():
        left = budget_s - (time.monotonic() - t0)
        if left < 15:
            print(f"SKIP (time) {c.name}", flush=True)
            continue
        cmd = [sys.executable, "-m", "mgpusim.cli", "run", str(c.experiment), "--devices", devices,
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
    v = sub.add_parser("validate")
    v.add_argument("--measured", type=Path, default=MEASURED)
    v.add_argument("--profile", default=str(PROFILE))
    v.add_argument("--out", type=Path, default=ROOT / "out" / "h200_validate")
    v.add_argument("--set", dest="extra", action="append", default=[])
    args = p.parse_args(argv)
    if args.cmd == "run":
        run_all(args.out, args.devices, args.budget)
        return 0
    from .validate import error_stats  # noqa: PLC0415
    table = validate_saved(args.measured, args.profile, args.out, extra=args.extra)
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "errors.csv", index=False)
    stats = error_stats(table)
    (args.out / "errors.json").write_text(json.dumps(stats, indent=2))
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.to_string(index=False))
    print(json.dumps(stats, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
