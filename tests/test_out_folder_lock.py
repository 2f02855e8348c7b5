"""The output-folder lock (`mgpusim.io.out_folder.locked_out_dir`): a second process writing a
held folder is refused at once naming the holder, the lock goes with its holder however it
dies, and the study commands and `mgpusim main` take it before any work."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest

from mgpusim.cli import main
from mgpusim.io.out_folder import LOCK_FILE, locked_out_dir
from mgpusim.model.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
#: A process that holds the folder given it until its stdin closes.
HOLDER = ("import sys\nfrom pathlib import Path\nfrom mgpusim.io.out_folder import locked_out_dir\n"
          "with locked_out_dir(Path(sys.argv[1])):\n    print('held', flush=True)\n    sys.stdin.read()\n")


@pytest.fixture
def holder(tmp_path: Path) -> Iterator[tuple[subprocess.Popen, Path]]:
    """Another process holding tmp_path/out (it has said so before the test runs)."""
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    assert proc.stdout is not None and proc.stdout.readline() == "held\n"
    yield proc, out
    if proc.poll() is None:
        proc.kill()
    proc.wait()


def test_a_second_writer_is_refused_naming_the_holder(holder):
    proc, out = holder
    with pytest.raises(InputError, match=rf"another mgpusim is writing {out} \(pid {proc.pid}\)"):
        with locked_out_dir(out):
            pytest.fail("the block ran in a folder another process holds")
    assert proc.poll() is None  # the holder was not disturbed


def test_the_lock_is_free_once_its_holder_ends_or_is_killed(holder):
    proc, out = holder
    proc.send_signal(signal.SIGKILL)  # no cleanup runs: the kernel drops the lock
    proc.wait()
    with locked_out_dir(out) as held:
        assert held == out and (out / LOCK_FILE).read_text().strip() == str(os.getpid())
    with locked_out_dir(out):  # released at the end of the block
        pass


def test_a_failed_block_leaves_no_folder_it_made_and_keeps_one_it_found(tmp_path):
    made = tmp_path / "new" / "out"
    with pytest.raises(RuntimeError), locked_out_dir(made):
        raise RuntimeError("the work failed")
    assert not made.exists()
    found = tmp_path / "found"
    found.mkdir()
    (found / "notes.txt").write_text("mine")
    with pytest.raises(RuntimeError), locked_out_dir(found):
        raise RuntimeError("the work failed")
    assert (found / "notes.txt").read_text() == "mine"


def test_a_path_that_is_a_file_is_an_input_error(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="exists and is not a folder"), locked_out_dir(tmp_path / "f"):
        pass


@pytest.mark.parametrize("command", [
    ["study", "calibrate", "experiments/lavapipe/study.toml"],
    ["study", "validate", "experiments/lavapipe/study.toml", "--no-figures"],
    ["study", "run", "experiments/lavapipe/study.toml"],
    ["main"],
], ids=["calibrate", "validate", "run", "main"])
def test_study_commands_refuse_a_held_folder_before_any_work(holder, command, capsys, monkeypatch):
    proc, out = holder
    monkeypatch.chdir(ROOT)
    code = main([*command, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert f"another mgpusim is writing {out} (pid {proc.pid})" in err[0]
    assert sorted(p.name for p in out.iterdir()) == [LOCK_FILE]  # nothing written
