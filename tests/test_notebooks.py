"""The notebooks run top to bottom in a real kernel (nbclient), their own `assert` cells hold,
and the copies in the repository keep their outputs (refresh them with
`python scripts/execute_notebooks.py`)."""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))

pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
nbformat = pytest.importorskip("nbformat")


def _execute():
    spec = importlib.util.spec_from_file_location("execute_notebooks", ROOT / "scripts" / "execute_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.execute


def _kinds(cell) -> list[str]:
    """What a cell showed: text, a table, a picture (not the values, which may be timings)."""
    out: list[str] = []
    for o in cell.get("outputs", []):
        kind = "image" if "image/png" in o.get("data", {}) else o["output_type"]
        if not (kind == "stream" and out and out[-1] == "stream"):  # prints split where they like
            out.append(kind)
    return out


def test_the_three_first_notebooks_are_there():
    assert {p.stem for p in NOTEBOOKS} >= {"what_if", "reading_a_timeline", "calibrating_a_machine"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_and_keeps_its_outputs(path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    fresh = _execute()(path, timeout=120)  # raises CellExecutionError on any failing cell or assert
    saved = nbformat.read(path, as_version=4)
    fresh_code = [c for c in fresh.cells if c.cell_type == "code"]
    saved_code = [c for c in saved.cells if c.cell_type == "code"]
    assert [c.source for c in saved_code] == [c.source for c in fresh_code]
    assert all(c.get("execution_count") for c in saved_code), "saved without running: execute and save it"
    assert [_kinds(c) for c in saved_code] == [_kinds(c) for c in fresh_code], "saved outputs are stale"
    assert any("image" in _kinds(c) for c in saved_code)
    assert not any(o.get("output_type") == "error" for c in saved_code for o in c.outputs)
