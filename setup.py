"""Packaging beyond what pyproject.toml can say: the checkout's `experiments/` and
`hardware_profiles/` ship inside the package (as mgpusim/experiments/ and
mgpusim/hardware_profiles/), so a wheel install has them and an experiment's relative
profile path (`../hardware_profiles/tc1.toml`) resolves there as in the checkout."""
from pathlib import Path

from setuptools import find_namespace_packages, setup

SHIPPED = {"mgpusim.experiments": "experiments", "mgpusim.hardware_profiles": "hardware_profiles"}


def shipped_packages() -> list[str]:
    """The shipped folders and their sub-folders, as package names."""
    out = []
    for package, folder in SHIPPED.items():
        for sub in [Path(folder), *sorted(p for p in Path(folder).rglob("*") if p.is_dir())]:
            if "__pycache__" not in sub.parts:
                out.append(".".join([package, *sub.relative_to(folder).parts]))
    return out


# Namespace packages too: mgpusim/real/passes/shaders/ has no __init__.py but ships its sources.
PACKAGES = find_namespace_packages(include=["mgpusim*"], exclude=["*__pycache__*"])
setup(packages=PACKAGES + shipped_packages(), package_dir=SHIPPED)
