"""C sources built into shared libraries on first use and cached, as the shaders are compiled.

Why: the runner's native core (and the probes that time a Vulkan call in C) ship as C source,
not binaries. The library's name carries the source's hash, so an edited source never reuses a
stale build; a compiler is only needed on a cache miss, so a machine without one (the NVIDIA
hosts) runs from a cache filled elsewhere (MGPUSIM_CACHE).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

from mgpusim.model.errors import DependencyError
from mgpusim.real.vulkan.shader_cache import cache_dir


def built(source: Path, folder: Path | None = None) -> Path:
    """`source` built with cc (`$CC`) as `<folder>/<stem>-<hash>.so`, unless it is there
    already; `folder` defaults to the cache's `native/` (`$MGPUSIM_CACHE/native`)."""
    text = source.read_bytes()
    folder = folder if folder is not None else cache_dir().parent / "native"
    target = folder / f"{source.stem}-{hashlib.sha256(text).hexdigest()[:16]}.so"
    if target.is_file():
        return target
    cc = shutil.which(os.environ.get("CC", "cc"))
    if cc is None:
        raise DependencyError(f"building {source.name} needs a C compiler (cc), or {target.name} "
                              f"brought into {folder} (MGPUSIM_CACHE)")
    folder.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(f".{os.getpid()}.tmp")
    done = subprocess.run([cc, "-O2", "-shared", "-fPIC", "-pthread", "-o", str(partial), str(source)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        partial.unlink(missing_ok=True)
        raise DependencyError(f"building {source.name} failed: {done.stderr.strip()[-400:]}")
    partial.replace(target)  # whole or not at all: another process may be building it too
    return target
