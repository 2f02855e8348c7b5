"""benchmarks/thread_start.py, the probe of `host.thread_start_ns`: run as a user runs it."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler")
def test_the_probe_prints_both_figures_per_thread() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "thread_start.py"), "--trials", "40",
                          "--batch", "3", "--json"], check=True, capture_output=True, text=True).stdout
    result = json.loads(out)
    assert result["batch"] == 3 and result["trials"] == 40
    # a thread start and join takes microseconds on any machine, never nothing, never a second
    assert 100 < result["single_ns"] < 10**9 and 100 < result["batch_ns"] < 10**9


def test_bad_counts_are_one_usage_error() -> None:
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "thread_start.py"), "--trials", "0"],
                          capture_output=True, text=True)
    assert done.returncode == 2 and "--trials" in done.stderr and "Traceback" not in done.stderr
