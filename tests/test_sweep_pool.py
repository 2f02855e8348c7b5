"""The sweep's points run with fewer garbage collections (mgpusim/sweeps/pool.py), and the
collector is left as it was found: thresholds back, a freeze undone, a caller's own kept."""
from __future__ import annotations

import gc
from pathlib import Path

from mgpusim.sweeps import grid as sweeps
from mgpusim.sweeps import pool

ROOT = Path(__file__).resolve().parents[1]


def test_collections_are_fewer_inside_and_as_before_after():
    before = gc.get_threshold()
    assert gc.get_freeze_count() == 0
    with pool.fewer_collections():
        assert gc.get_threshold() == pool.POINT_GC_THRESHOLDS
        assert gc.get_freeze_count() > 0
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0


def test_a_callers_freeze_stays_theirs():
    gc.freeze()
    try:
        with pool.fewer_collections():
            pass
        # still frozen (unfrozen, the count would be 0; a frozen object freed since lowers it)
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_a_sweep_in_this_process_leaves_the_collector_as_it_was(monkeypatch):
    seen = []
    point = sweeps.run_point

    def spy(*args, **kwargs):
        seen.append(gc.get_threshold())
        return point(*args, **kwargs)
    monkeypatch.setattr(sweeps, "run_point", spy)
    before = gc.get_threshold()
    df = sweeps.sweep(ROOT / "experiments" / "sort_first_tc1.toml", {"schedule.gpus": [1, 2]},
                      overrides={"schedule.frames": 12}, workers=1, progress=False)
    assert df["error"].isna().all() and seen == [pool.POINT_GC_THRESHOLDS] * 2
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0
