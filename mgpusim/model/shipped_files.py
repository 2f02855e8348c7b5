"""Where the shipped experiments and hardware profiles lie, wherever mgpusim is installed: in a
checkout, the repository's `experiments/` and `hardware_profiles/` beside the package; in a
wheel, inside the package. Here, at the bottom of the package, because the model itself reads
the shipped profiles (the ranges a what-if is judged against), not only the commands."""
from __future__ import annotations

from pathlib import Path

from mgpusim.model.errors import InputError

PACKAGE = Path(__file__).resolve().parents[1]  # mgpusim/, this module being in mgpusim/model/


def shipped_dir(name: str) -> Path:
    """`experiments` or `hardware_profiles`: inside the package when installed from a wheel,
    else the checkout's folder beside the package."""
    for candidate in (PACKAGE / name, PACKAGE.parent / name):
        if candidate.is_dir():
            return candidate
    raise InputError(f"the shipped {name}/ folder is missing from this installation ({PACKAGE})")
