"""Fuzz the input loaders: mutate the shipped experiments and hardware profiles at random and
check that every failure is mgpusim's own error (MgpusimError, printed as one line), never a
crash (any other exception: a traceback for the user).

    PYTHONPATH=. python scripts/fuzz_inputs.py --cases 5000 --seed 1

Each case takes one shipped file, applies 1-3 mutations (a value replaced by an odd one:
NaN, infinities, huge or negative numbers, wrong types, long strings; a key deleted; a key
added or misspelt; the TOML text itself flipped or cut), then loads it, builds the schedule,
checks memory and runs the engine (frames capped at FRAMES_CAP so that a valid but long
mutation stays fast; the frame count does not change the code paths taken). One case in five
mutates a shipped measure table instead (data/lavapipe/*.csv: cells, columns, rows) and
calibrates from it, least-squares fits included; one in five gives a shipped experiment
`--set` overrides instead (a random dotted key of the experiment or, as `profile.<key>`, of its
profile, sometimes with `*` or a bad index, and an odd value). It prints the
counts of outcomes (ok, error, crash), the slowest case, and each crash with its mutation.
Exit status 1 if any case crashed. tests/test_fuzz_loaders.py runs the same cases under
Hypothesis.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import random
import sys
import time
import tomllib
import traceback
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.model.errors import MgpusimError  # noqa: E402
from mgpusim.model.profile import parse_profile  # noqa: E402
from mgpusim.model.toml_checks import read_toml  # noqa: E402
from mgpusim.schedules.experiment import load_experiment, parse_experiment  # noqa: E402
from mgpusim.sim.simulation import simulate  # noqa: E402

#: Frames simulated per case at most (see the module docstring).
FRAMES_CAP = 12
#: Experiments of the simulate format (experiments/h200/configs.toml etc. are lists of runs).
EXPERIMENTS = sorted(p for p in (ROOT / "experiments").rglob("*.toml")
                     if "schedule" in tomllib.loads(p.read_text()))
PROFILES = sorted((ROOT / "hardware_profiles").glob("*.toml"))
TABLES = sorted((ROOT / "data" / "lavapipe").glob("*.csv"))
ODD_CELLS: tuple[Any, ...] = ("", "nan", "inf", "-inf", -1, 0, 1, 1e300, -1e300, "x", "mesh_v2",
                              2**64, 0.5, "copy_h2d", "host_copy", "graphics", "transfer")

ODD_VALUES: tuple[Any, ...] = (
    0, -1, 1, 2, 3, 7, 64, 65, 1024, 10**6, 2**31, 2**53 + 1, 2**63, 2**64, 10**30, -10**30,
    0.0, -0.0, 0.5, -2.5, 1e-300, 1e-9, 1e12, 1e300, -1e300, math.nan, math.inf, -math.inf,
    True, False, "", "x", "0", "nan", "graphics", "peer", "host", "fragment_loop", "\n\t",
    "é" * 3, "x" * 5000, [], [0], [1, 2], [0, 0], ["a"], [[1]], {}, {"a": 1}, {"count": 2},
)


@dataclasses.dataclass
class Case:
    kind: str  # "experiment", "profile", "table" or "override"
    source: Path
    mutations: list[str]
    data: dict[str, Any] | None  # None when the TOML text itself was mutated
    text: str | None = None
    table: Any = None  # a mutated measure table (pandas DataFrame)
    overrides: dict[str, Any] | None = None  # --set overrides of a shipped experiment


def make_case(rng: random.Random) -> Case:
    """One mutated shipped file (a dict, or broken TOML text one time in eight, or a measure
    table one time in five)."""
    roll = rng.random()
    if roll < 0.2:
        return make_table_case(rng)
    if roll < 0.4:
        return make_override_case(rng)
    kind = rng.choice(("experiment", "profile"))
    source = rng.choice(EXPERIMENTS if kind == "experiment" else PROFILES)
    if rng.random() < 0.125:
        text, what = mutate_text(source.read_text(), rng)
        return Case(kind, source, [what], None, text)
    data = read_toml(source)
    if kind == "experiment":
        data["profile"] = str((source.parent / data["profile"]).resolve())
    mutations = [mutate(data, rng) for _ in range(rng.randint(1, 3))]
    return Case(kind, source, mutations, data)


def make_table_case(rng: random.Random) -> Case:
    import pandas as pd  # noqa: PLC0415

    source = rng.choice(TABLES)
    df = pd.read_csv(source, dtype=object)
    mutations = []
    for _ in range(rng.randint(1, 3)):
        op = rng.random()
        if op < 0.7 and len(df):
            row, col = rng.randrange(len(df)), rng.choice(list(df.columns))
            value = rng.choice(ODD_CELLS)
            df.loc[df.index[row], col] = str(value)
            mutations.append(f"row {row} {col} = {short(value)}")
        elif op < 0.85:
            col = rng.choice(list(df.columns))
            df = df.drop(columns=[col])
            mutations.append(f"drop column {col}")
        else:
            df = df.iloc[: rng.randrange(max(1, len(df) // 4))]
            mutations.append(f"keep {len(df)} rows")
    return Case("table", source, mutations, None, table=df)


def make_override_case(rng: random.Random) -> Case:
    source = rng.choice(EXPERIMENTS)
    exp_data = read_toml(source)
    overrides = {}
    for _ in range(rng.randint(1, 3)):
        if rng.random() < 0.5:
            profile = read_toml((source.parent / exp_data["profile"]).resolve())
            key = "profile." + dotted_key(profile, rng)
        else:
            key = dotted_key(exp_data, rng)
        value = rng.choice(ODD_VALUES)
        overrides[key] = copy.deepcopy(value)
    return Case("override", source, [f"--set {k}={short(v)}" for k, v in overrides.items()], None,
                overrides=overrides)


def dotted_key(data: dict[str, Any], rng: random.Random) -> str:
    """A random dotted path into `data` as --set takes it; list indices sometimes '*' or bad."""
    parts: list[str] = []
    node: Any = data
    while isinstance(node, (dict, list)) and node and (not parts or rng.random() < 0.7):
        if isinstance(node, dict):
            key = rng.choice(list(node))
            parts.append(str(key))
            node = node[key]
        else:
            i = rng.randrange(len(node))
            parts.append(rng.choice((str(i), str(i), "*", str(len(node) + 3), "x")))
            node = node[i]
    if rng.random() < 0.2:
        parts.append(misspell(parts[-1], rng) if parts else "x")
    return ".".join(parts)


def mutate(data: dict[str, Any], rng: random.Random) -> str:
    """Change one place of `data` in place; return what was done."""
    parent, key = pick(data, rng)
    op = rng.random()
    if op < 0.55:
        value = rng.choice(ODD_VALUES)
        old = parent[key]
        if isinstance(old, (int, float)) and not isinstance(old, bool) and rng.random() < 0.5:
            # a plausible number, same type: valid more often, so the model runs on it
            value = type(old)(old * rng.choice((-1, 0, 0.5, 2, 10, 1000, 10**6, 10**12, 0.001)))
        parent[key] = copy.deepcopy(value)
        return f"{key} = {short(value)}"
    if op < 0.7 and isinstance(parent, dict):
        del parent[key]
        return f"del {key}"
    if op < 0.85 and isinstance(parent, dict):
        typo = misspell(str(key), rng)
        parent[typo] = parent[key] if rng.random() < 0.5 else rng.choice(ODD_VALUES)
        if rng.random() < 0.7:
            del parent[key]
        return f"{key} -> {typo}"
    if isinstance(parent[key], list) and parent[key]:
        parent[key].append(copy.deepcopy(rng.choice(parent[key])))
        return f"{key} += copy of an entry"
    parent[key] = {"nested": copy.deepcopy(parent[key])}
    return f"{key} wrapped in a table"


def pick(data: dict[str, Any], rng: random.Random) -> tuple[Any, Any]:
    """A random (container, key) in the tree, deeper places as likely as shallow ones."""
    places: list[tuple[Any, Any]] = []

    def walk(node: Any) -> None:
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for k, v in items:
            places.append((node, k))
            if isinstance(v, (dict, list)):
                walk(v)
    walk(data)
    return rng.choice(places)


def misspell(word: str, rng: random.Random) -> str:
    if len(word) < 2:
        return word + "x"
    i = rng.randrange(len(word) - 1)
    return rng.choice((word[:i] + word[i + 1:],                         # a letter dropped
                       word[:i] + word[i + 1] + word[i] + word[i + 2:],  # two swapped
                       word + "s", word.upper()))


def mutate_text(text: str, rng: random.Random) -> tuple[str, str]:
    i = rng.randrange(len(text))
    op = rng.randrange(4)
    if op == 0:
        return text[:i], f"cut at {i}"
    if op == 1:
        return text[:i] + chr(rng.randrange(0, 0x2FF)) + text[i + 1:], f"char {i} replaced"
    if op == 2:
        return text[:i] + text[i:].replace("=", "== ", 1), f"doubled '=' after {i}"
    return text[:i] + "\0" + text[i:], f"NUL at {i}"


def run_case(case: Case, tmp: Path) -> str:
    """'ok' or 'error'; anything but MgpusimError propagates (a crash)."""
    try:
        if case.kind == "table":
            return run_table_case(case, tmp)
        if case.kind == "override":
            simulate(capped(load_experiment(case.source, case.overrides)), record_trace=False)
            return "ok"
        if case.text is not None:
            path = tmp / case.source.name
            path.write_text(case.text, encoding="utf-8", errors="surrogatepass")
            data = read_toml(path)
        else:
            data = case.data
        if case.kind == "profile":
            profile = parse_profile(data, case.source.name)
            exp_data = read_toml(ROOT / "experiments" / "sort_first_tc1.toml")
            exp = parse_experiment(exp_data, "sort_first_tc1.toml", profile=profile)
        else:
            exp = parse_experiment(data, case.source.name, base=case.source.parent)
        simulate(capped(exp), record_trace=False)
        return "ok"
    except MgpusimError:
        return "error"


def run_table_case(case: Case, tmp: Path) -> str:
    """Calibrate from the mutated table and write the profile in memory (checked on load)."""
    from mgpusim.calibration import apply, calibrate, lavapipe_base, read_measurements  # noqa: PLC0415

    path = tmp / case.source.name
    case.table.to_csv(path, index=False)
    df, machine = read_measurements([path])
    apply(calibrate(df, machine), lavapipe_base(machine), "fuzz")
    return "ok"


def capped(exp: Any) -> Any:
    sched = exp.schedule
    frames = min(sched.frames, FRAMES_CAP)
    return dataclasses.replace(exp, schedule=dataclasses.replace(
        sched, frames=frames, warmup_frames=min(sched.warmup_frames, frames - 1)))


def short(value: Any) -> str:
    text = repr(value)
    return text if len(text) < 40 else text[:37] + "..."


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=5000)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    import tempfile  # noqa: PLC0415

    rng = random.Random(args.seed)
    counts: Counter[str] = Counter()
    kinds: Counter[tuple[str, str]] = Counter()
    slowest = (0.0, "")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(args.cases):
            case = make_case(rng)
            start = time.monotonic()
            try:
                outcome = run_case(case, Path(tmp))
            except Exception as exc:  # noqa: BLE001 - a crash is what this script looks for
                outcome = "crash"
                print(f"CRASH case {n}: {case.kind} {case.source.name} {case.mutations}: "
                      f"{type(exc).__name__}: {short(str(exc))}", file=sys.stderr)
                traceback.print_exc(limit=-3)
            took = time.monotonic() - start
            if took > slowest[0]:
                slowest = (took, f"case {n}: {case.source.name} {case.mutations}")
            counts[outcome] += 1
            kinds[(case.kind, outcome)] += 1
    print(f"cases {args.cases} (seed {args.seed}) in {time.monotonic() - t0:.0f} s: "
          f"ok {counts['ok']}, error (MgpusimError) {counts['error']}, crash {counts['crash']}")
    print("by kind: " + ", ".join(f"{k} {o} {n}" for (k, o), n in sorted(kinds.items())))
    print(f"slowest {slowest[0]:.2f} s: {slowest[1]}")
    return 1 if counts["crash"] else 0


if __name__ == "__main__":
    sys.exit(main())
