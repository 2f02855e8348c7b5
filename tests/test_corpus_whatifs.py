"""A held-out style corpus over what-ifs, sweeps and case studies: profile overrides of every
kind of value (bad, extreme, plausible, unused), drawing windows, fidelity levels, sweep grids
and case files, each run through the command line and classified (tests/corpus_harness.py).

What counts as a correct result is a property a user relies on, not a number: a plausible
override takes effect in the right direction (a slower rate never makes the frame faster),
an extreme one is refused naming the override or carries a warning naming it, a level that
approximates lists what it leaves out."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import pandas as pd
import pytest

from tests.corpus_harness import CLEAN_ERROR, CORRECT, Case, names, run_case

EXP = "sort_first_tc1"
FAST = ["--fidelity", "analytic", "--no-progress"]
#: Profile keys of TC1 that a sort-first frame reads, and whether a larger value is faster.
RATES = {"host.memory_bandwidth_gbps": True, "host.memcpy_thread_gbps": True, "gpus.0.link.lanes": True,
         "gpus.0.link.efficiency": True, "gpus.*.speed": True}
COSTS = {"host.host_copy_fixed_ns": False, "gpus.0.link.latency_ns": False,
         "gpus.0.costs.fragment_loop.ns_per_pixel_iteration": False, "gpus.0.costs.fragment_loop.fixed_ns": False,
         "gpus.*.costs.composite_sort_first.ns_per_pixel": False, "gpus.1.costs.present.fixed_ns": False,
         "gpus.0.copy.transfer.fixed_ns": False}
KEYS = {**RATES, **COSTS}
BAD_VALUES = {"negative": "-1", "nan": "nan", "inf": "inf", "text": '"fast"', "bool": "true", "list": "[1, 2]"}


def _simulate(*argv: str) -> Callable[[Path], list[str]]:
    return lambda tmp: ["simulate", EXP, "--out", str(tmp / "out"), *FAST, *argv]


def _summary(tmp: Path) -> dict:
    return json.loads((tmp / "out" / "summary.json").read_text())


_BASELINE: dict[str, float] = {}


def _baseline(tmp: Path) -> float:
    """The unchanged experiment's frame time (computed once)."""
    if "frame_time_ms" not in _BASELINE:
        from mgpusim.cli import main
        assert main(["simulate", EXP, "--out", str(tmp / "baseline"), *FAST]) == 0
        _BASELINE["frame_time_ms"] = json.loads((tmp / "baseline" / "summary.json").read_text())["frame_time_ms"]
    return _BASELINE["frame_time_ms"]


def _direction(key: str, faster_when_larger: bool, factor: float) -> Callable[[Path, str], bool]:
    """The override moved the frame time the way its mechanism says (or left it where it is:
    the value may lie off the critical path), and the run took it (no warning: in range)."""
    def check(tmp: Path, _out: str) -> bool:
        now, before = _summary(tmp)["frame_time_ms"], _baseline(tmp)
        slower = (factor < 1) == faster_when_larger
        return now >= before * (1 - 1e-9) if slower else now <= before * (1 + 1e-9)
    return check


def _warned(key: str) -> Callable[[Path, str], bool]:
    def check(tmp: Path, _out: str) -> bool:
        return any(key in w for w in _summary(tmp).get("warnings", []))
    return check


def _value(key: str, factor: float) -> str:
    """`factor` times TC1's value of `key` (as its file has it; a GPU's speed is 1 where the
    file gives none; integers stay integers)."""
    import tomllib
    node: object = tomllib.loads((Path(__file__).resolve().parents[1] / "hardware_profiles" / "tc1.toml").read_text())
    for part in key.replace("*", "0").split("."):
        node = node[int(part)] if part.isdigit() else node.get(part, 1.0)  # type: ignore[index,union-attr]
    if isinstance(node, int) and not isinstance(node, bool):
        return str(max(1, round(node * factor)))
    return repr(float(node) * factor)  # type: ignore[arg-type]


def override_cases() -> list[Case]:
    cases = []
    for key in KEYS:
        short = key.split(".")[-1]
        for label, value in BAD_VALUES.items():
            cases.append(Case(f"set-{key}-{label}", _simulate("--set", f"profile.{key}={value}"), (short,)))
        for label, factor in (("tiny", 1e-9), ("huge", 1e9)):
            if key.endswith(("lanes", "efficiency")) and factor > 1:
                continue  # bounded above by their meaning: covered by the refusals below
            if key in COSTS and factor < 1:
                continue  # a cost near zero is a plausible bound, not an extrapolation
            cases.append(Case(f"set-{key}-{label}", lambda tmp, k=key, f=factor: _simulate(
                "--set", f"profile.{k}={_value(k, f)}")(tmp), (short, "profile." + key),
                check=_warned(key), either=True))
    for key, faster in KEYS.items():
        for factor in (0.5, 1.5):
            if key.endswith(("efficiency", "lanes")) and factor > 1:
                continue  # at most 1; a power of two
            cases.append(Case(f"whatif-{key}-x{factor}", lambda tmp, k=key, f=factor: _simulate(
                "--set", f"profile.{k}={_value(k, f)}")(tmp), check=_direction(key, faster, factor)))
    cases += [
        Case("set-efficiency-above-one", _simulate("--set", "profile.gpus.0.link.efficiency=1.5"), ("efficiency",)),
        Case("set-lanes-fraction", _simulate("--set", "profile.gpus.0.link.lanes=2.5"), ("lanes",)),
        Case("set-lanes-zero", _simulate("--set", "profile.gpus.0.link.lanes=0"), ("lanes",)),
        Case("set-speed-1e-12", _simulate("--set", "profile.gpus.*.speed=1e-12"), ("profile.gpus.*.speed",)),
        Case("set-unused-particle-cost", _simulate("--set", "profile.gpus.0.costs.particle_update.fixed_ns=5"),
             ("particle_update",)),
        Case("set-unused-local-copy", _simulate("--set", "profile.gpus.0.local_copy_gbps=100"), ("local_copy_gbps",)),
        Case("set-unused-mesh-cost", _simulate("--set", "profile.gpus.*.costs.mesh.ns_per_triangle=2"), ("mesh",)),
        Case("set-typo-key", _simulate("--set", "profile.host.memory_bandwith_gbps=3"), ("memory_bandwith_gbps",)),
        Case("set-gpu-index-beyond", _simulate("--set", "profile.gpus.9.speed=2"), ("gpus",)),
        Case("set-unknown-section", _simulate("--set", "profile.nope=1"), ("nope",)),
        Case("set-no-value", _simulate("--set", "profile.host.cpu_cores"), ("profile.host.cpu_cores",)),
        Case("set-empty-key", _simulate("--set", "=3"), ("--set",)),
        Case("set-gpus-zero", _simulate("--set", "schedule.gpus=0"), ("gpus",)),
        Case("set-gpus-too-many", _simulate("--set", "schedule.gpus=65"), ("gpus",)),
        Case("set-width-negative", _simulate("--set", "scene.width=-5"), ("width",)),
        Case("set-scene-typo", _simulate("--set", "scene.widht=5"), ("widht",)),
        Case("set-cpu-cores-zero", _simulate("--set", "profile.host.cpu_cores=0"), ("cpu_cores",)),
    ]
    return cases


def window_cases() -> list[Case]:
    def clipped(tmp: Path, out: str) -> bool:
        return "draws frames" in out and (tmp / "out" / "timeline.png").is_file()

    def approximations(expected: bool) -> Callable[[Path, str], bool]:
        def check(tmp: Path, out: str) -> bool:
            listed = _summary(tmp).get("approximations") or []
            return bool(listed) == expected and (not expected or "approximations" in out)
        return check
    lavapipe = lambda *a: lambda tmp: ["simulate", "lavapipe/sort_first", "--out", str(tmp / "out"),  # noqa: E731
                                       "--no-progress", *a]
    return [
        Case("frames-past-the-end", _simulate("--frames", "0:1000000"), check=clipped),
        Case("frames-start-past-the-end", _simulate("--frames", "100000:100010"), ("--frames",)),
        Case("frames-backwards", _simulate("--frames", "50:40"), ("--frames",)),
        Case("frames-text", _simulate("--frames", "a:b"), ("--frames",)),
        Case("frames-negative", _simulate("--frames", "-5:3"), ("--frames",)),
        Case("frames-empty", _simulate("--frames", "3:3"), ("--frames",)),
        Case("queues-says-what-it-leaves-out", lavapipe("--fidelity", "queues"), check=approximations(True)),
        Case("analytic-says-what-it-leaves-out", lavapipe("--fidelity", "analytic"), check=approximations(True)),
        Case("full-leaves-nothing-out", lavapipe(), check=approximations(False)),
        Case("effects-off-says-so", lavapipe("--effects", "-shared_executor"), check=approximations(True)),
        Case("effects-unknown", lavapipe("--effects", "-sharedexecutor"), ("sharedexecutor",)),
        Case("fidelity-unknown", lavapipe("--fidelity", "exact"), ("--fidelity",)),
    ]


# ----- sweeps --------------------------------------------------------------------------------------
def _sweep(*argv: str) -> Callable[[Path], list[str]]:
    return lambda tmp: ["sweep", EXP, "--out", str(tmp / "out"), "--fidelity", "analytic", "--workers", "1",
                        "--no-progress", *argv]


def _swept(points: int, column: str = "frame_time_ms") -> Callable[[Path, str], bool]:
    def check(tmp: Path, _out: str) -> bool:
        table = pd.read_parquet(tmp / "out" / "sweep.parquet")
        return len(table) == points and table["error"].isna().all() and table[column].map(math.isfinite).all()
    return check


def _every_point_failed(reason: str) -> Callable[[Path, str], bool]:
    """The documented end of a sweep of no good point: exit 1, the folder written, the reason."""
    def check(tmp: Path, out: str) -> bool:
        return "every point failed" in out and reason in out and (tmp / "out" / "sweep.parquet").is_file()
    return check


def _failed_row_names(field: str) -> Callable[[Path, str], bool]:
    """A point that cannot run is a row with its error (naming the field), listed as failed."""
    def check(tmp: Path, out: str) -> bool:
        table = pd.read_parquet(tmp / "out" / "sweep.parquet")
        errors = table["error"].dropna()
        return len(errors) == 1 and field in errors.iloc[0] and "1 failed" in out
    return check


def _sweep_with_failed_point(tmp: Path, out: str) -> bool:
    table = pd.read_parquet(tmp / "out" / "sweep.parquet")
    return len(table) == 2 and table["error"].notna().sum() == 1 and "fail" in out


def _resumed_after_profile_edit(tmp: Path) -> list[str]:
    """A sweep, its experiment's profile edited, the same sweep again into the same folder."""
    root = Path(__file__).resolve().parents[1]
    exp = (root / "experiments" / f"{EXP}.toml").read_text()
    (tmp / "p.toml").write_text((root / "hardware_profiles" / "tc1.toml").read_text())
    (tmp / "e.toml").write_text(exp.replace('profile = "../hardware_profiles/tc1.toml"', 'profile = "p.toml"'))
    from mgpusim.cli import main
    argv = ["sweep", str(tmp / "e.toml"), "--out", str(tmp / "out"), "--fidelity", "analytic", "--workers", "1",
            "--no-progress", "--grid", "scene.width=512,1024"]
    assert main(argv) == 0
    _BASELINE["swept"] = float(pd.read_parquet(tmp / "out" / "sweep.parquet")["frame_time_ms"].sum())
    text = (tmp / "p.toml").read_text().replace("ns_per_pixel_iteration = 0.0016", "ns_per_pixel_iteration = 0.0032")
    (tmp / "p.toml").write_text(text)
    return argv


def _recomputed(tmp: Path, _out: str) -> bool:
    return float(pd.read_parquet(tmp / "out" / "sweep.parquet")["frame_time_ms"].sum()) > _BASELINE["swept"] * 1.5


def sweep_cases() -> list[Case]:
    return [
        Case("sweep-unknown-key", _sweep("--grid", "scene.widht=1,2"), ("widht",)),
        Case("sweep-no-values", _sweep("--grid", "scene.width="), ("scene.width",)),
        Case("sweep-no-equals", _sweep("--grid", "scene.width"), ("scene.width",)),
        Case("sweep-unused-profile-key", _sweep("--grid", "profile.gpus.0.costs.mesh.fixed_ns=1,2"),
             check=_every_point_failed("costs.mesh.fixed_ns: unused"), exits=(1,)),
        Case("sweep-workers-zero", _sweep("--grid", "scene.width=512,1024", "--workers", "0"), ("--workers",)),
        Case("sweep-out-is-a-file", lambda tmp: [*_sweep("--grid", "scene.width=512")(tmp)[:3],
                                                 str((tmp / "f").write_text("x") and tmp / "f"),
                                                 *_sweep("--grid", "scene.width=512")(tmp)[4:]], ("f",)),
        Case("sweep-bad-fidelity", _sweep("--grid", "scene.width=512", "--fidelity", "exact"), ("--fidelity",)),
        Case("sweep-bad-value-type", _sweep("--grid", "schedule.gpus=two,3"), check=_failed_row_names("gpus")),
        Case("sweep-a-failing-point", _sweep("--grid", "profile.gpus.*.speed=1,1e-12"), check=_sweep_with_failed_point),
        Case("sweep-two-keys", _sweep("--grid", "scene.width=512,1024", "--grid", "schedule.gpus=1,2"), check=_swept(4)),
        Case("sweep-profile-rate", _sweep("--grid", "profile.host.memory_bandwidth_gbps=10,20,30"), check=_swept(3)),
        Case("sweep-resume-after-profile-edit", _resumed_after_profile_edit, check=_recomputed),
        Case("sweep-too-many-points", _sweep("--grid", "scene.width=" + ",".join(map(str, range(64, 64 + 400))),
                                             "--grid", "scene.height=" + ",".join(map(str, range(64, 64 + 400)))),
             ("points",)),
    ]


# ----- case studies ----------------------------------------------------------------------------------
def _case_file(text: str) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        (tmp / "case.toml").write_text(text)
        return ["case", str(tmp / "case.toml"), "--out", str(tmp / "out"), "--no-progress"]
    return make


def _shipped_case(edit: Callable[[str], str]) -> Callable[[Path], list[str]]:
    """The vulkan thesis case file copied beside its experiments' copies, then edited."""
    def make(tmp: Path) -> list[str]:
        import shutil
        root = Path(__file__).resolve().parents[1]
        shutil.copytree(root / "experiments" / "cases" / "vulkan_thesis", tmp / "case")
        shutil.copytree(root / "hardware_profiles", tmp / "hardware_profiles")
        case = tmp / "case" / "case.toml"
        case.write_text(edit(case.read_text()))
        return ["case", str(case), "--out", str(tmp / "out"), "--no-progress", "--frames", "60"]
    return make


def case_cases() -> list[Case]:
    return [
        Case("case-unknown-name", lambda tmp: ["case", "no_such_case", "--out", str(tmp / "out")], ("no_such_case",)),
        Case("case-not-toml", _case_file("[case\n"), ("case.toml",)),
        Case("case-empty", _case_file(""), ("case.toml",)),
        Case("case-binary", lambda tmp: (tmp.joinpath("case.toml").write_bytes(b"\0\1"),
                                         ["case", str(tmp / "case.toml")])[1], ("case.toml",)),
        Case("case-frames-zero", lambda tmp: ["case", "vulkan_thesis", "--frames", "0", "--out", str(tmp / "o")],
             ("--frames",)),
        Case("case-frames-text", lambda tmp: ["case", "vulkan_thesis", "--frames", "many"], ("--frames",)),
        Case("case-out-is-a-file", lambda tmp: ["case", "vulkan_thesis", "--out",
                                                str((tmp / "f").write_text("x") and tmp / "f")], ("f",)),
        Case("case-a-folder", lambda tmp: ["case", str(tmp)], ("folder", "case.toml")),
        Case("case-unknown-key", _shipped_case(lambda t: t + "\nnope = 1\n"), ("nope",)),
        Case("case-experiment-missing", _shipped_case(lambda t: t.replace("sort_first.toml", "sort_frist.toml", 1)),
             ("sort_frist.toml",)),
    ]


# ----- advise: refused before the search, never a hang or a mixed folder -----------------------------
def _frame(passes: int, extra: str = "") -> Callable[[Path], Path]:
    """A one-GPU experiment of `passes` passes, imported from a CSV capture."""
    def make(tmp: Path) -> Path:
        rows = "".join(f"p{i},graphics,{0.1 + i % 7 * 0.05:.2f},{extra}\n" for i in range(passes))
        (tmp / "frame.csv").write_text(f"pass,queue,gpu_ms,pixel_share\n{rows}".replace(",\n", ",1\n"))
        from mgpusim.cli import main
        assert main(["frame", "import", str(tmp / "frame.csv"), "--size", "1280x720", "--out", str(tmp / "f")]) == 0
        return tmp / "f" / "frame.toml"
    return make


def _advise(*argv: str, frame: Callable[[Path], Path] = _frame(4)) -> Callable[[Path], list[str]]:
    return lambda tmp: ["advise", str(frame(tmp)), "--out", str(tmp / "out"), "--workers", "1", *argv]


def _advise_while_locked(tmp: Path) -> list[str]:
    """advise into a folder another writer holds (the lock taken here, as a second mgpusim would)."""
    import contextlib

    from mgpusim.io.out_folder import locked_out_dir
    stack = contextlib.ExitStack()
    stack.enter_context(locked_out_dir(tmp / "out"))
    _HELD.append(stack)  # released by the test after the case
    return _advise()(tmp)


_HELD: list = []


def _advise_over_earlier(tmp: Path) -> list[str]:
    """An advice of a 6-pass frame already in the folder; then the 3-pass frame's into it."""
    from mgpusim.cli import main
    first = tmp / "first"
    first.mkdir()
    assert main(["advise", str(_frame(6)(first)), "--out", str(tmp / "out"), "--workers", "1", "--max-gpus", "1"]) == 0
    return ["advise", str(_frame(3)(tmp)), "--out", str(tmp / "out"), "--workers", "1", "--max-gpus", "1"]


def _only_the_new_advice(tmp: Path, _out: str) -> bool:
    """The folder holds the second frame's advice alone: its report, table and timelines."""
    advice = json.loads((tmp / "out" / "advice.json").read_text())
    text = json.dumps(advice)
    listed = sorted(p.name for p in (tmp / "out").iterdir() if not p.name.startswith("."))
    return ("p5" not in text and "p2" in text and (tmp / "out" / "report.html").is_file()
            and "advice.csv" in listed and not (tmp / "out" / ".advice-partial").exists())


def advise_cases() -> list[Case]:
    return [
        Case("advise-missing-experiment", lambda tmp: ["advise", str(tmp / "none.toml")], ("none.toml",)),
        Case("advise-two-gpu-experiment", lambda tmp: ["advise", EXP, "--out", str(tmp / "out")], ("gpus",)),
        Case("advise-max-gpus-zero", _advise("--max-gpus", "0"), ("--max-gpus",)),
        Case("advise-max-gpus-text", _advise("--max-gpus", "all"), ("--max-gpus",)),
        Case("advise-max-gpus-beyond", _advise("--max-gpus", "99"), ("--max-gpus",)),
        Case("advise-confirm-negative", _advise("--confirm", "-1"), ("--confirm",)),
        Case("advise-timelines-negative", _advise("--timelines", "-2"), ("--timelines",)),
        Case("advise-workers-zero", _advise("--workers", "0"), ("--workers",)),
        Case("advise-out-is-a-file", lambda tmp: [*_advise()(tmp)[:2], "--out",
                                                  str((tmp / "f.txt").write_text("x") and tmp / "f.txt")], ("f.txt",)),
        Case("advise-folder-held-by-another", _advise_while_locked, ("another mgpusim",)),
        Case("advise-frame-past-the-limit", _advise(frame=_frame(65)), ("65",)),
        Case("advise-bad-override", _advise("--set", "profile.gpus.*.speed=-1"), ("speed",)),
        Case("advise-unknown-override", _advise("--set", "scene.widht=5"), ("widht",)),
        Case("advise-over-an-earlier-advice", _advise_over_earlier, check=_only_the_new_advice),
    ]


CASES = override_cases() + window_cases() + sweep_cases() + case_cases() + advise_cases()


@pytest.mark.parametrize("case", CASES, ids=list(names(CASES)))
def test_case(case: Case, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    try:
        outcome = run_case(case, tmp_path, lambda: tuple(capsys.readouterr()))  # type: ignore[arg-type,return-value]
    finally:
        while _HELD:
            _HELD.pop().close()
    expected = (CLEAN_ERROR, CORRECT) if case.either else (CORRECT,) if case.check else (CLEAN_ERROR,)
    assert outcome.kind in expected, f"{outcome.kind}: {outcome.detail}"
