"""The busy_wake effect: a copy's thread woken just as another GPU's pass fills the cores.

Measured on lavapipe (several GPUs emulated on two cores): a pass that keeps every core busy
wakes its rasterizer threads as it starts; a copy of another GPU whose thread wakes in the
first moments of that pass is often placed behind them on one core. It waits there while the
other core idles -- a few scheduler ticks (5-8 ms at 250 Hz), or until the pass is done if that
comes first -- so the pass runs on one core and the copy, and the hand-offs after it, start
late. The model's fair share of the cores has none of that, which made alternate-frame
rendering on 3-4 GPUs 15-19 % too fast.

The model: when a copy is about to start within `window_ns` of the start of another GPU's
core-filling pass (lasting at least `window_ns` itself), the pair (that pass, the copy's GPU)
counts once; of the pairs, a share `share` -- dealt out in a fixed order by a running credit, no
randomness -- make the copy wait first: `ns`, or the pass's remaining work if less, as one core's
time on the shared cores (a core idle meanwhile, so the pass runs on the other). The share and
the wait are the host's, measured on the calibration runs' traces."""
from __future__ import annotations

from collections import defaultdict
from fractions import Fraction

from mgpusim.model.costs import round_half_up

#: A pass "fills the cores" when its kind keeps at least this share of the host's cores busy:
#: the fragment-heavy kinds (about 2 of 2 cores); a mesh pass (about 1.5) leaves a core free.
FILLS_CORES = Fraction(9, 10)


class BusyWake:
    """The effect's state in one simulation: which GPUs' core-filling passes are running, since
    when and with how much work, which (pass, GPU) pairs have counted, and the credit.

    Kept in integers where the hot path touches it (a pass starts, a copy is about to): the
    credit in units of 1 / the share's denominator, a pass's work as its cores and its time
    alone (its core-ns are their product). `state()` gives the same Fractions as before."""

    def __init__(self, share: float, ns: int, window_ns: int, host_cores: int) -> None:
        self.share, self.ns, self.window_ns = Fraction(repr(share)), ns, window_ns
        self._filling_cores = FILLS_CORES * host_cores
        #: the credit x the share's denominator (`_unit`); the share adds `_step` of them
        self._step, self._unit = self.share.numerator, self.share.denominator
        self._credit_units = 0
        self._running: dict[str, int] = defaultdict(int)  # device -> filling passes running
        #: device -> its latest filling pass: (start, cores, duration alone in ns)
        self._latest: dict[str, tuple[int, Fraction, int]] = {}
        self._counted: set[tuple[str, str]] = set()  # (pass device, copy device)

    @property
    def credit(self) -> Fraction:
        """The running credit (each pair that counts adds the share; a wait takes 1 off)."""
        return Fraction(self._credit_units, self._unit)

    def fills(self, cores: Fraction, duration_ns: int) -> bool:
        """Whether a pass keeping `cores` busy for `duration_ns` (alone) counts as filling."""
        return cores >= self._filling_cores and duration_ns >= self.window_ns

    def pass_started(self, device: str, now: int, cores: Fraction, duration_ns: int) -> None:
        self._running[device] += 1
        self._latest[device] = (now, cores, duration_ns)
        if self._counted:
            self._counted = {p for p in self._counted if p[0] != device}

    def pass_ended(self, device: str) -> None:
        self._running[device] -= 1

    def copy_wait(self, device: str, now: int) -> int:
        """The wait (ns of one core's time) of a copy of `device` about to start at `now`: 0, or
        for the pair whose share brings the credit to 1, `ns` or the young pass's work left
        (taken as done at full speed so far) if less: once the pass is done its threads sleep."""
        latest, window = self._latest, self.window_ns
        young = None  # (start, device) of the latest young pass of another GPU
        for d, n in self._running.items():  # (`_young`, inline)
            if n and d != device:
                start = latest[d][0]
                if now - start <= window and (young is None or (start, d) > young):
                    young = (start, d)
        if young is None:
            return 0
        pass_device = young[1]
        pair = (pass_device, device)
        if pair in self._counted:
            return 0
        self._counted.add(pair)
        self._credit_units += self._step
        if self._credit_units < self._unit:
            return 0
        self._credit_units -= self._unit
        start, cores, duration = latest[pass_device]
        left = max(cores * (duration - (now - start)), Fraction(0))  # its core-ns left
        return min(self.ns, round_half_up(left))

    def _young(self, now: int) -> list[str]:
        return [d for d, n in self._running.items()
                if n and now - self._latest[d][0] <= self.window_ns]

    def state(self, now: int) -> tuple:
        """What decides its future, relative to `now` (for the fast-forward's repeat check): the
        credit, the running passes (the young ones with their start, cores and core-ns) and the
        young passes' pairs that counted."""
        young = set(self._young(now))
        return (self.credit,
                tuple(sorted((d, n) + ((now - self._latest[d][0], self._latest[d][1],
                                        self._latest[d][1] * self._latest[d][2])
                                       if d in young else ())
                             for d, n in self._running.items() if n)),
                tuple(sorted(p for p in self._counted if p[0] in young)))
