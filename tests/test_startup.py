"""Start-up of the command line: `mgpusim --version` and `--help` import no command module and
none of the model's libraries; a command's module is imported when that command is used; the
names listed before any module loads are the ones the modules register. (The time itself is a
benchmark's: benchmarks/startup.py. Here, what is imported.)"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mgpusim import cli
from mgpusim.cli import COMMAND_HELP, COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pandas", "simpy", "matplotlib", "scipy", "pyarrow")


def _imported_after(code: str) -> dict[str, list[str]]:
    """Run `code` in a fresh interpreter; which of HEAVY and which command modules it imported."""
    probe = (f"import sys\n{code}\n"
             "import json\n"
             f"print(json.dumps({{'heavy': sorted(m for m in {HEAVY!r} if m in sys.modules), "
             "'commands': sorted(m for m in sys.modules if m.startswith('mgpusim.commands.'))}))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT,
                         check=True, timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_importing_the_cli_and_building_its_parser_imports_none_of_the_model():
    seen = _imported_after("from mgpusim.cli import build_parser\n"
                           "p = build_parser()\np.format_help()\np.format_usage()")
    assert seen == {"heavy": [], "commands": []}


@pytest.mark.parametrize("argv", [["--version"], ["--help"]])
def test_version_and_help_import_no_command_module(argv):
    seen = _imported_after(f"from mgpusim.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass")
    assert seen == {"heavy": [], "commands": []}


@pytest.mark.parametrize("command", ["simulate", "sweep"])
def test_a_commands_help_imports_that_command_alone_and_no_model(command):
    seen = _imported_after(f"from mgpusim.cli import main\ntry:\n    main([{command!r}, '--help'])\n"
                           "except SystemExit:\n    pass")
    assert seen == {"heavy": [], "commands": [f"mgpusim.commands.{command}"]}


def test_the_listed_help_is_what_each_module_registers():
    """COMMAND_HELP (what --help shows before any module loads) against the help each
    command's `register` gives, once every parser is built."""
    parser = build_parser()
    sub = parser._subparsers._group_actions[0]
    assert list(sub.choices) == [cli.command_name(m) for m in COMMANDS] == list(COMMAND_HELP)
    before = {a.dest: a.help for a in sub._choices_actions}
    assert before == COMMAND_HELP
    built = dict(sub.choices.items())  # builds every command's parser
    assert all(p is not None for p in built.values())
    after = {a.dest: a.help for a in sub._choices_actions}
    assert list(after) == list(COMMAND_HELP)  # each command once, in its place
    registered = {k: v for k, v in after.items() if not (v or "").startswith("(unavailable here")}
    assert {"simulate", "sweep", "study", "examples"} <= set(registered)
    assert registered == {k: COMMAND_HELP[k] for k in registered}


def test_the_effect_and_fidelity_names_are_the_models():
    from mgpusim.sim import effects
    from mgpusim.sim.effect_names import EFFECT_NAMES, FIDELITIES

    assert tuple(effects.EFFECTS) == EFFECT_NAMES
    assert effects.FIDELITIES is FIDELITIES


def test_simulate_offers_the_models_names():
    from mgpusim.sim.effects import EFFECTS, FIDELITIES

    parser = build_parser()
    simulate = parser._subparsers._group_actions[0].choices["simulate"]
    fidelity = next(a for a in simulate._actions if a.dest == "fidelity")
    effects = next(a for a in simulate._actions if a.dest == "effects")
    assert tuple(fidelity.choices) == FIDELITIES
    assert ", ".join(EFFECTS) in effects.help


def test_a_command_is_built_once_and_its_numbers_are_strict(capsys):
    parser = build_parser()
    sub = parser._subparsers._group_actions[0]
    first = sub.choices["simulate"]
    assert sub.choices["simulate"] is first
    rows = next(a for a in first._actions if a.dest == "trace_rows")
    assert rows.type is cli.whole_number
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "x", "--trace-rows", "nan"])
    assert "invalid int value" in capsys.readouterr().err


def test_an_unknown_command_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulat"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "invalid choice: 'simulat'" in err and "'simulate'" in err and "'advise'" in err
