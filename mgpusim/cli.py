"""The `mgpusim` command line: one sub-command per module in :mod:`mgpusim.commands`.

Each command module exposes ``register(subparsers)`` which adds its parser and sets
``func(args) -> int``. Errors meant for users (:class:`MgpusimError`) print as one line.
"""
from __future__ import annotations

import argparse
import importlib
import math
import re
import sys
from typing import NoReturn

from mgpusim import __version__
from mgpusim.model.errors import MgpusimError

#: Packages that only the Vulkan backend needs: the `vulkan` extra installs them.
VULKAN_PACKAGES = ("vulkan", "cffi")

#: Command modules, in the order `mgpusim --help` lists them.
COMMANDS = ("simulate", "sweep", "examples", "case", "run", "bench", "fidelity", "devices", "measure", "calibrate",
            "validate", "study", "main_job", "frame", "advise")


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line, like every other error (the usage is one --help away)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def one_line(text: str) -> str:
    """A message on one line: newlines, NULs and other control characters from a file's key or
    value (or a name given on the command line) are shown escaped."""
    return text.translate(_ESCAPES)


#: Control characters as Python writes them in a string (\n, \x00, \x85, ...), except the tab:
#: every character str.splitlines() breaks at (C0, DEL, C1, the line and paragraph separators).
_ESCAPES = {c: repr(chr(c))[1:-1] if c < 0x2028 else f"\\u{c:04x}"
            for c in (*range(32), *range(127, 160), 0x2028, 0x2029) if c != 9}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mgpusim", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"mgpusim {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"mgpusim.commands.{name}")
        except ModuleNotFoundError as exc:  # a command not written yet, or a missing dependency
            if exc.name != f"mgpusim.commands.{name}":
                package = (exc.name or "?").split(".")[0]
                install = "'mgpusim[vulkan]'" if package in VULKAN_PACKAGES else package
                # e.g. no scipy on a device machine: the other commands still run
                _unavailable(sub, name, f"needs {exc.name}",
                             f"needs the Python package {package!r} (pip install {install})")
            continue
        except MgpusimError as exc:  # e.g. an installation without its shipped experiments
            _unavailable(sub, name, "cannot start here", one_line(str(exc)))
            continue
        module.register(sub)
    _strict_numbers(parser)
    return parser


def _strict_numbers(parser: argparse.ArgumentParser) -> None:
    """Every `type=int` / `type=float` option of every command, read strictly: ASCII digits
    only (int() also takes '١٢' and '²'-free Unicode digits), integers of at most 18 digits
    (int64), and finite floats (float() takes 'nan' and 'inf')."""
    for action in parser._actions:
        if action.type is int:
            action.type = whole_number
        elif action.type is float:
            action.type = finite_number
        for sub in (action.choices or {}).values() if isinstance(action.choices, dict) else ():
            if isinstance(sub, argparse.ArgumentParser):
                _strict_numbers(sub)


_WHOLE = re.compile(r"[+-]?[0-9]{1,18}")
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]{1,3})?")


def whole_number(text: str) -> int:
    """An integer option: ASCII digits, at most 18 of them."""
    if not _WHOLE.fullmatch(text.strip()):
        digits = text.strip().lstrip("+-")
        why = "at most 18 digits" if digits.isascii() and digits.isdigit() else "ASCII digits"
        raise argparse.ArgumentTypeError(f"invalid int value: {text[:40]!r} (a whole number in {why})")
    return int(text)


def finite_number(text: str) -> float:
    """A number option: ASCII digits with an optional fraction and exponent, finite."""
    if not _DECIMAL.fullmatch(text.strip()) or not math.isfinite(float(text)):
        raise argparse.ArgumentTypeError(f"invalid float value: {text[:40]!r} (a finite "
                                         "number in ASCII digits)")
    return float(text)


def _unavailable(sub: argparse._SubParsersAction, name: str, why: str, message: str) -> None:
    """A command whose module cannot load here: listed (`why`), and one line if used."""
    command = name.replace("_job", "").replace("_", "-")
    p = sub.add_parser(command, help=f"(unavailable here: {why})", add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER, help="ignored")

    def fail(args: argparse.Namespace) -> int:
        print(f"mgpusim {command}: error: {message}", file=sys.stderr)
        return 2
    p.set_defaults(func=fail)


#: Options whose value may start with "-" (`--effects -task_gaps`): argparse would read such a
#: value as another option, so it is joined to its option first (`--effects=-task_gaps`).
SIGNED_VALUE_OPTIONS = ("--effects",)


def join_signed_values(argv: list[str]) -> list[str]:
    """`--effects -x` as `--effects=-x`; everything else as given."""
    out: list[str] = []
    args = iter(argv)
    for arg in args:
        if arg in SIGNED_VALUE_OPTIONS:
            value = next(args, None)
            if value is not None and value[:1] in "+-" and not value.startswith("--"):
                out.append(f"{arg}={value}")
                continue
            out.append(arg)
            if value is not None:
                out.append(value)
            continue
        out.append(arg)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = join_signed_values(sys.argv[1:] if argv is None else list(argv))
    for i, arg in enumerate(argv):  # no file or key has a NUL in its name (the OS refuses it)
        if "\0" in arg:
            print(f"mgpusim: error: argument {i + 1} ({arg[:60]!r}) holds a NUL character",
                  file=sys.stderr)
            return 2
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except MgpusimError as exc:
        print(f"mgpusim {args.command}: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system refused (disk full, permissions, a name too long)
        where = f"{str(exc.filename)[:80]}: " if exc.filename else ""
        print(f"mgpusim {args.command}: error: {where}{one_line(exc.strerror or str(exc))}",
              file=sys.stderr)
        return 2
    except MemoryError:  # the run's tables grow with its frames (docs/input_checks.md, bounds)
        print(f"mgpusim {args.command}: error: out of memory (fewer schedule.frames, or a machine "
              "with more memory); nothing was left in the output folder", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
