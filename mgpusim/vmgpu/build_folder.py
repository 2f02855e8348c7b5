"""An already-built vmgpu build folder, checked before anything runs, and what it was built from.

Why check first: a measurement takes half an hour; a folder without the executable or its
compiled shaders (vmgpu opens `spv/*.spv` relative to its working directory) would fail on the
first run, or worse, run a different vmgpu. The source folder and its commits (vmgpu's and its bp
submodule's) come from the build's CMake cache, for the provenance.
"""
from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from mgpusim.vmgpu.failures import NotABuildError

EXECUTABLE = "vmgpu"
SHADERS = ("basic.vert.spv", "basic.frag.spv")


@dataclass(frozen=True)
class Build:
    """A checked build folder: its executable, and from the CMake cache (where there is one) the
    source folder and build type."""

    folder: Path
    executable: Path
    source: Path | None
    build_type: str


def check_build(folder: Path) -> Build:
    """The build in `folder`, or NotABuildError saying what is missing."""
    folder = folder.resolve()
    if not folder.is_dir():
        raise NotABuildError(f"{folder} is not a vmgpu build folder: no such folder")
    exe = folder / EXECUTABLE
    if not exe.is_file() or not os.access(exe, os.X_OK):
        raise NotABuildError(f"{folder} is not a vmgpu build folder: it has no executable "
                             f"'{EXECUTABLE}'")
    missing = [s for s in SHADERS if not (folder / "spv" / s).is_file()]
    if missing:
        raise NotABuildError(f"{folder} is not a vmgpu build folder: its spv/ lacks "
                             f"{', '.join(missing)} (vmgpu loads its shaders from there)")
    cache = _cmake_cache(folder / "CMakeCache.txt")
    source = cache.get("CMAKE_HOME_DIRECTORY") or cache.get("vmgpu_SOURCE_DIR")
    return Build(folder=folder, executable=exe, source=Path(source) if source else None,
                 build_type=cache.get("CMAKE_BUILD_TYPE", "unknown") or "unknown")


def _cmake_cache(path: Path) -> dict[str, str]:
    """NAME -> value of a CMakeCache.txt (empty where there is none)."""
    if not path.is_file():
        return {}
    values = {}
    for line in path.read_text(errors="replace").splitlines():
        if line and not line.startswith(("#", "//")) and "=" in line and ":" in line.split("=")[0]:
            key, value = line.split("=", 1)
            values[key.split(":")[0]] = value
    return values


def commit(folder: Path | None) -> str:
    """The git commit checked out in `folder`, with '+dirty' where its files differ from it
    (a patched checkout), or 'unknown' where it is not a git checkout."""
    if folder is None or not folder.is_dir():
        return "unknown"
    try:
        head = _git(folder, "rev-parse", "HEAD")
        dirty = _git(folder, "status", "--porcelain", "--untracked-files=no", "--ignore-submodules=all")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def _git(folder: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True,
                          check=True, timeout=30).stdout.strip()
