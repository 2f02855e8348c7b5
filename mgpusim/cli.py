"""The `mgpusim` command line: one sub-command per module in :mod:`mgpusim.commands`.

Each command module exposes ``register(subparsers)`` which adds its parser and sets
``func(args) -> int``. Errors meant for users (:class:`MgpusimError`) print as one line.

A command's module is imported only when that command is used (or its parser is asked for):
`mgpusim --version` and `mgpusim --help` list the commands from :data:`COMMAND_HELP` and import
none of them, so they start in about the time of a bare interpreter (benchmarks/startup.py).
"""
from __future__ import annotations

import argparse
import importlib
import math
import re
import sys
from typing import Any, NoReturn

from mgpusim import __version__
from mgpusim.model.errors import MgpusimError

#: Packages that only the Vulkan backend needs: the `vulkan` extra installs them.
VULKAN_PACKAGES = ("vulkan", "cffi")

#: Command modules, in the order `mgpusim --help` lists them.
COMMANDS = ("simulate", "sweep", "examples", "case", "run", "bench", "fidelity", "devices", "measure", "calibrate",
            "validate", "study", "main_job", "frame", "advise")

#: What `mgpusim --help` says of each command before its module is loaded: the help its
#: `register` gives (a test checks they are the same).
COMMAND_HELP = {
    "simulate": "run an experiment in the model and write its results",
    "sweep": "run an experiment over a grid of overrides into one Parquet table",
    "examples": "list the shipped experiments (their names work as EXPERIMENT)",
    "case": "run a case study (a source system's own setup) and write its predictions",
    "run": "run an experiment's schedule on Vulkan devices (measured)",
    "bench": "simulated frames per second against a hand-written SimPy model of the same frame, cost per "
             "event and per resource use vs raw SimPy",
    "fidelity": "error vs measured runs and simulation time, per fidelity level",
    "devices": "list Vulkan devices, queues and extensions",
    "measure": "time Vulkan passes over parameter sweeps",
    "calibrate": "fit profile coefficients to measurement tables",
    "validate": "run a schedule for real and in the model, report the errors",
    "study": "measure, calibrate and validate a study (a set of configurations)",
    "main": "the main job: the lavapipe study (measure, calibrate, validate, report)",
    "frame": "bring your own frame: import a profiler capture as an experiment",
    "advise": "search schedules, GPU counts and links for a frame; an HTML report",
}


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


def command_name(module: str) -> str:
    """The command a module of :mod:`mgpusim.commands` registers (`main_job` -> `main`)."""
    return module.replace("_job", "").replace("_", "-")


def build_parser() -> argparse.ArgumentParser:
    """The whole command line; each command's own parser is built from its module on first
    use (see :class:`_Commands`)."""
    parser = _Parser(prog="mgpusim", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"mgpusim {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", action=_Commands)
    assert isinstance(sub, _Commands)
    for module in COMMANDS:
        sub.add_lazy(command_name(module), module)
    _strict_numbers(parser)
    return parser


class _Commands(argparse._SubParsersAction):
    """The sub-commands, each listed (name and help) at once and built by its module's
    `register` only when argparse looks it up: parsing `mgpusim simulate ...` imports
    :mod:`mgpusim.commands.simulate` alone, and `--help` or `--version` none of them. Asking
    for every parser (`choices.items()`, as a walk over the whole command line does) builds
    them all."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._lazy: dict[str, str] = {}  # command -> module, until built
        self._listed: dict[str, argparse.Action] = {}  # command -> its line in --help
        self._name_parser_map = self.choices = _LazyParsers(self)

    def add_lazy(self, name: str, module: str) -> None:
        """List `name` with its help; its module is imported when it is first looked up."""
        line = self._ChoicesPseudoAction(name, (), COMMAND_HELP.get(name))
        self._choices_actions.append(line)
        self._listed[name] = line
        self._lazy[name] = module

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        """As argparse's, except that a command listed already keeps its place in --help
        (its line takes the help its module gives)."""
        line = self._listed.get(name)
        parser = super().add_parser(name, **kwargs)
        if line is not None and "help" in kwargs:
            line.help = self._choices_actions.pop().help
        self._lazy.pop(name, None)
        return parser

    def load(self, name: str) -> None:
        """Build the parser of command `name` from its module (or one that says, in one line
        when used, why the module cannot load here)."""
        module = self._lazy.pop(name)
        try:
            loaded = importlib.import_module(f"mgpusim.commands.{module}")
        except ModuleNotFoundError as exc:  # a missing dependency, or a command not written yet
            if exc.name == f"mgpusim.commands.{module}":
                _unavailable(self, module, "not installed", "this installation lacks the command")
            else:
                package = (exc.name or "?").split(".")[0]
                install = "'mgpusim[vulkan]'" if package in VULKAN_PACKAGES else package
                # e.g. no scipy on a device machine: the other commands still run
                _unavailable(self, module, f"needs {exc.name}",
                             f"needs the Python package {package!r} (pip install {install})")
        except MgpusimError as exc:  # e.g. an installation without its shipped experiments
            _unavailable(self, module, "cannot start here", one_line(str(exc)))
        else:
            loaded.register(self)
        if name in self._lazy:  # the module registered another name: nothing answers to it
            del self._lazy[name]
            _unavailable(self, module, "not registered", "the command's module did not register it")
        _strict_numbers(dict.__getitem__(self._name_parser_map, name))


class _LazyParsers(dict):
    """Command name -> parser, building each on first look-up (:meth:`_Commands.load`); its
    names (iteration, `in`, the list in an error) are every command's, built or not."""

    def __init__(self, owner: _Commands):
        super().__init__()
        self._owner = owner

    def __missing__(self, name: str) -> argparse.ArgumentParser:
        if name not in self._owner._lazy:
            raise KeyError(name)
        self._owner.load(name)
        return dict.__getitem__(self, name)

    def __contains__(self, name: object) -> bool:
        return dict.__contains__(self, name) or name in self._owner._lazy

    def _names(self) -> list[str]:
        return [*self._owner._listed, *(n for n in dict.keys(self) if n not in self._owner._listed)]

    def __iter__(self):
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())

    def keys(self):
        return self._names()

    def get(self, name: str, default: object = None) -> object:
        return self[name] if name in self else default

    def items(self):
        return [(n, self[n]) for n in self._names()]

    def values(self):
        return [self[n] for n in self._names()]


def _strict_numbers(parser: argparse.ArgumentParser) -> None:
    """Every `type=int` / `type=float` option of every command, read strictly: ASCII digits
    only (int() also takes '١٢' and '²'-free Unicode digits), integers of at most 18 digits
    (int64), and finite floats (float() takes 'nan' and 'inf')."""
    for action in parser._actions:
        if action.type is int:
            action.type = whole_number
        elif action.type is float:
            action.type = finite_number
        if isinstance(action, _Commands):
            continue  # each command's parser is made strict as it is built
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
    command = command_name(name)
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
