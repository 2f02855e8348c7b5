"""GLSL sources shipped in the package, compiled to SPIR-V on first use and cached.

Why: shaders stay readable GLSL in the repository (no binaries checked in), but a compile per
run would cost ~50 ms per shader. The cache key is the hash of the source and its name, so
editing a shader never reuses a stale binary; the compiler is only needed on a cache miss, so a
machine without one (the NVIDIA hosts) runs from a cache filled elsewhere (MGPUSIM_CACHE).
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

from mgpusim.model.errors import DependencyError
from mgpusim.real.vulkan.vk_errors import require_compiler

# The GLSL sources belong to the pass library (real/passes/shaders/); this module only compiles.
SHADER_DIR = Path(__file__).resolve().parents[1] / "passes" / "shaders"


def cache_dir() -> Path:
    """`$MGPUSIM_CACHE/spirv`, else `$XDG_CACHE_HOME/mgpusim/spirv`, else ~/.cache/..."""
    root = os.environ.get("MGPUSIM_CACHE")
    if root:
        return Path(root) / "spirv"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "mgpusim" / "spirv"


@lru_cache(maxsize=None)
def spirv(name: str) -> bytes:
    """The SPIR-V of `shaders/<name>` (e.g. `fullscreen.vert`), compiling it if not cached."""
    source_path = SHADER_DIR / name
    source = source_path.read_bytes()
    key = hashlib.sha256(b"\0".join([source, name.encode()]))
    target = cache_dir() / f"{source_path.stem}-{source_path.suffix[1:]}-{key.hexdigest()[:16]}.spv"
    if target.exists():
        return target.read_bytes()
    compiler = require_compiler()
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.spv"
        cmd = [*compiler, "-o", str(out), str(source_path)]
        if compiler[0] == "glslc":
            cmd.insert(1, "-O")
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise DependencyError(f"compiling {name} failed: {proc.stderr.strip()}")
        code = out.read_bytes()
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, suffix=".tmp")
    with os.fdopen(fd, "wb") as fh:  # write then rename: concurrent runs never see half a file
        fh.write(code)
    os.replace(tmp_name, target)
    return code
