"""Progress on the console for the commands that can run for seconds (simulate, bench,
fidelity, case): a bar on stderr with rate and ETA that appears only once the work has taken a
second, so that a quick command prints nothing more than its results.

The model and the studies report through plain callbacks (`progress(done, total)`); only the
commands draw, here.
"""
from __future__ import annotations

import sys
from typing import Any, Callable

#: seconds before a bar appears
DELAY_S = 1.0


def bar(total: int | None, desc: str, unit: str = "it", enabled: bool = True) -> Any:
    """A tqdm bar on stderr (a context manager); `enabled` False draws nothing."""
    from tqdm import tqdm  # noqa: PLC0415 (loaded only by the commands that draw)
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, delay=DELAY_S,
                dynamic_ncols=True, file=sys.stderr, leave=False)


def reporter(progress_bar: Any) -> Callable[[int, int], None]:
    """A `progress(done, total)` callback that moves `progress_bar` (its total may change: a
    fast-forward shortens the run it reports on)."""
    def report(done: int, total: int) -> None:
        if progress_bar.total != total:
            progress_bar.total = total
        progress_bar.update(done - progress_bar.n)
    return report
