"""Output paths checked before any work: a run that cannot write its results should fail in
the first second, not after the simulation or measurement."""
from __future__ import annotations

import os
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
