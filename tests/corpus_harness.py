"""Running a corpus of bad (and a few good) inputs through the command line and classifying
each outcome as a user would see it: a clean error, a correct result, a traceback, a hang, or a
silent wrong result (a command that finishes as if nothing were wrong, or an error that names
neither the file nor the field at fault)."""
from __future__ import annotations

import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from mgpusim.cli import main

#: The outcome classes; the corpus passes when every case is one of the first two.
CLEAN_ERROR, CORRECT, TRACEBACK, HANG, SILENT_WRONG = (
    "clean error", "correct result", "traceback", "hang", "silent wrong result")
#: Seconds before a case counts as a hang (the slowest good case takes a few).
HANG_S = 120


@dataclass(frozen=True)
class Case:
    """One input: `make(tmp)` writes what it needs under `tmp` and returns the argv. An error
    case names the strings of which one must be in the error line (the file, the field); a
    result case checks the output folder and the printed text (`check`), exits with one of
    `exits` and prints each of `warns`."""

    name: str
    make: Callable[[Path], list[str]]
    names: tuple[str, ...] = ()
    check: Callable[[Path, str], bool] | None = None
    exits: tuple[int, ...] = (0, 1)
    warns: tuple[str, ...] = field(default=())
    #: a result case that may instead be refused (exit 2, naming one of `names`): an extreme
    #: value that the model either bounds with an error or runs with a warning
    either: bool = False


@dataclass(frozen=True)
class Outcome:
    kind: str
    detail: str


class _Hang(BaseException):
    pass


def _alarm(_signum: int, _frame: object) -> None:
    raise _Hang()


def run_case(case: Case, tmp: Path, capture: Callable[[], tuple[str, str]]) -> Outcome:
    """Run `case` in this process (a fresh interpreter per case would take the whole test
    budget) under an alarm; `capture()` returns (stdout, stderr) since the last call."""
    argv = case.make(tmp)
    capture()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_S)
    try:
        code = _exit_code(argv)
    except _Hang:
        return Outcome(HANG, f"no answer in {HANG_S} s")
    except BaseException as exc:  # noqa: BLE001 - the point: anything escaping is a traceback
        return Outcome(TRACEBACK, f"{type(exc).__name__}: {exc}"[:300])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    out, err = capture()
    return _classify(case, code, out, err, tmp)


def _exit_code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own refusals
        return exc.code if isinstance(exc.code, int) else 2


def _classify(case: Case, code: int, out: str, err: str, tmp: Path) -> Outcome:
    errors = [line for line in err.splitlines() if "error:" in line]
    if case.check is None or (case.either and code == 2):  # an error is expected (or allowed)
        if code != 2 or not errors:
            return Outcome(SILENT_WRONG, f"exit {code}, expected a refusal; stderr: {err[-300:]}")
        if case.names and not any(n in errors[-1] for n in case.names):
            return Outcome(SILENT_WRONG, f"the error names none of {case.names}: {errors[-1]}")
        return Outcome(CLEAN_ERROR, errors[-1])
    if code not in case.exits:
        return Outcome(SILENT_WRONG, f"exit {code}, expected one of {case.exits}: {err[-300:]}")
    missing = [w for w in case.warns if w not in err + out]
    if missing or not case.check(tmp, out + err):
        return Outcome(SILENT_WRONG, f"the result is not right (warnings missing: {missing}): {(out + err)[-300:]}")
    return Outcome(CORRECT, f"exit {code}")


def names(cases: list[Case]) -> Iterator[str]:
    """Each case's name, checked unique (a parametrized test needs distinct ids)."""
    seen = set()
    for c in cases:
        assert c.name not in seen, c.name
        seen.add(c.name)
        yield c.name
