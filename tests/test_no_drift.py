"""Long runs land exactly where arithmetic says: integer time never drifts."""
from __future__ import annotations

import numpy as np
import pytest

from mgpusim import simulate
from tests.conftest import make_experiment, profile_dict


@pytest.mark.parametrize("gpus, frames", [(1, 100_000), (2, 100_000)])
def test_period_constant_to_the_nanosecond(gpus, frames):
    """Odd byte counts and 7/3 B/ns links make every copy duration a rounded fraction."""
    prof = profile_dict(gpus=2, threads=3, mem_gbps=7 / 3, h2d=7 / 3, d2h=7 / 3, thread_gbps=1.1)
    exp = make_experiment(prof, gpus=gpus, frames=frames, width=37, height=11, iterations=23)
    result = simulate(exp, record_trace=False)
    periods = np.diff(result.frames.present_ns.to_numpy()[10:])
    assert periods.min() == periods.max()
    first = int(result.frames.present_ns.iloc[10])
    assert int(result.frames.present_ns.iloc[-1]) == first + (frames - 11) * int(periods[0])
