"""Progress on the console for the commands that can run for seconds (simulate, bench,
fidelity, case, advise): a bar on stderr with rate and ETA that appears only once the work has
taken a second, so that a quick command prints nothing more than its results.

The model and the studies report through plain callbacks (`progress(done, total)`, or
`progress(stage, done, total)` for work in stages: :class:`Stages`); only the
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


class Stages:
    """A `progress(stage, done, total)` callback for work in named stages (a search, then its
    confirmation, then a report): one bar per stage, each drawn only once its stage has taken
    :data:`DELAY_S`, so a long command never sits silent and a quick one prints nothing."""

    def __init__(self, prefix: str, unit: str = "it", enabled: bool = True):
        self.prefix, self.unit, self.enabled = prefix, unit, enabled
        self.stage: str | None = None
        self.bar: Any = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage != self.stage:
            self.close()
            self.stage, self.bar = stage, bar(total, f"{self.prefix}: {stage}", self.unit, self.enabled)
        reporter(self.bar)(done, total)

    def close(self) -> None:
        """Close the current stage's bar (it is erased from the console)."""
        if self.bar is not None:
            self.bar.close()
        self.stage, self.bar = None, None

    def __enter__(self) -> Stages:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
