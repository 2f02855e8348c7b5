"""Output paths checked before any work: a run that cannot write its results should fail in
the first second, not after the simulation or measurement; and an output folder held by one
process at a time (:func:`locked_out_dir`), so that two runs into one folder cannot interleave
their files.
"""
from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from mgpusim.model.errors import InputError


def check_out_dir(path: Path, option: str = "--out") -> None:
    """`path` is a folder, or one can be created there, and it can be written."""
    with _os_errors(path, option):
        _check_dir(path, option)


def check_out_file(path: Path, option: str = "--out") -> None:
    """A file can be written at `path` (its folder exists or can be created; it is not a folder)."""
    with _os_errors(path, option):
        _check_file(path, option)


@contextmanager
def _os_errors(path: Path, option: str) -> Iterator[None]:
    """A path the system refuses outright (a name too long, a loop of links) is an input error."""
    try:
        yield
    except OSError as exc:
        shown = str(path) if len(str(path)) <= 80 else str(path)[:80] + "..."
        raise InputError(f"cannot use {shown} ({exc.strerror or exc})", field=option) from None


def _check_dir(path: Path, option: str) -> None:
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} exists and is not a folder", field=option)
    _check_writable(path if path.exists() else _existing_ancestor(path, option), path, option)


def _check_file(path: Path, option: str) -> None:
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a file name", field=option)
    if path.exists():
        _check_writable(path.parent, path, option)
        return
    _check_writable(_existing_ancestor(path.parent, option), path, option)


def _existing_ancestor(path: Path, option: str) -> Path:
    """The nearest existing folder above `path` (where a new folder would be made); a file
    in the way is an error."""
    for parent in (path, *path.parents):
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"cannot create {path}: {parent} is a file", field=option)
            return parent
    return Path(".")


def _check_writable(folder: Path, path: Path, option: str) -> None:
    """Create and remove a probe file: permission bits alone miss read-only mounts and root."""
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".mgpusim-write-check-")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {folder} is not writable "
                         f"({exc.strerror or exc})", field=option) from None
    os.close(fd)
    os.unlink(probe)


#: The lock file a writing command holds in its output folder (left in place: see locked_out_dir).
LOCK_FILE = ".mgpusim.lock"


@contextmanager
def locked_out_dir(path: Path, option: str = "--out") -> Iterator[Path]:
    """The output folder `path`, checked, created and held by this process until the block
    ends: a second mgpusim writing it meanwhile is refused at once with an InputError naming
    this process (not left to wait, nor to mix its files with ours). Why flock: the kernel
    drops the lock when the holder dies, even by SIGKILL, so no stale lock needs clearing.
    The lock file stays in the folder after the block: removing it would let a process that
    opened it just before lock a file no one else sees. Where the folder was made here and holds
    only the lock when the block ends (it failed, or stopped before writing anything), the
    folder goes too: nothing is left that looks like output."""
    check_out_dir(path, option)
    made = not path.exists()
    with _os_errors(path, option):
        path.mkdir(parents=True, exist_ok=True)
        fd = os.open(path / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        _take(fd, path, option)
        try:
            yield path
        finally:  # failed, or ended without writing (a job that stopped before any work)
            if made:
                _remove_if_only_lock(path)
    finally:
        os.close(fd)  # releases the lock


def _take(fd: int, path: Path, option: str) -> None:
    """Lock `fd` without waiting and write our pid into it; a holder's pid in the error."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        raise InputError(f"another mgpusim is writing {path} (pid {holder})", field=option) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)


def _remove_if_only_lock(path: Path) -> None:
    """Remove a folder this process made whose only file is the lock (a run that failed)."""
    if [p.name for p in path.iterdir()] == [LOCK_FILE]:
        shutil.rmtree(path, ignore_errors=True)
