"""Affine stretches of the analytic recurrence: a period of frames run once for a whole range.

The recurrence (:mod:`mgpusim.sim.analytic`) only adds constants to times and compares them.
Where a state x and a guess d make every comparison of the next period (its maxima, the memcpy
thread picked, the skip rule, and the comparisons the repeat's state is written with) come out
the same for the state x + j d for every j in 0..k, and the period leads from x to x + d, each
of those periods leads from x + j d to x + (j + 1) d with the same decisions: every value is an
affine function of j on that range. So one pass over the period on values `a + b j`
(:class:`Lin`) stands for k + 1 periods, exactly (integer ns, same decisions, same ties).

Why it holds: with the decisions fixed, a period's outputs are the state's values plus
constants, so every compared difference is affine in j; an affine function with the same sign
(or zero throughout) at j = 0 and j = k has that sign for every j between. A comparison that
flips inside the range stops the pass (:class:`Indefinite`, with the last j before it flips),
and the caller tries the shorter range. This is what a transient looks like where one part of
the pipeline runs at its own rate and another at a slower one (a frame's latency growing by the
same amount every frame until the frames in flight fill): no state repeats there, but every
period is the one before it with each time moved by its own constant.
"""
from __future__ import annotations

from typing import Any


class Indefinite(Exception):
    """A comparison whose outcome changes over j = 0..span: it holds the same for j <= `last`."""

    def __init__(self, last: int):
        super().__init__(last)
        self.last = last


def _sign(a: int, b: int, span: int) -> int:
    """The sign of a + b j, the same for every j in 0..span, or Indefinite."""
    s0 = (a > 0) - (a < 0)
    if b == 0 or span == 0:
        return s0
    end = a + b * span
    if s0 != 0 and s0 == (end > 0) - (end < 0):
        return s0
    if s0 == 0:
        raise Indefinite(0)
    raise Indefinite((a - 1) // -b if s0 > 0 else (-a - 1) // b)


class Lin:
    """A time `a + b j` for every j in 0..span (j: periods into the stretch)."""

    __slots__ = ("a", "b", "span")
    #: a value, compared only (its == is not identity)
    __hash__ = None  # type: ignore[assignment]

    def __init__(self, a: int, b: int, span: int):
        self.a, self.b, self.span = a, b, span

    def __repr__(self) -> str:
        return f"Lin({self.a} + {self.b} j, j <= {self.span})"

    def at(self, j: int) -> int:
        return self.a + self.b * j

    def __add__(self, other: Any) -> "Lin":
        if isinstance(other, Lin):
            return Lin(self.a + other.a, self.b + other.b, self.span)
        return Lin(self.a + other, self.b, self.span)

    __radd__ = __add__

    def __sub__(self, other: Any) -> "Lin":
        if isinstance(other, Lin):
            return Lin(self.a - other.a, self.b - other.b, self.span)
        return Lin(self.a - other, self.b, self.span)

    def __rsub__(self, other: Any) -> "Lin":
        if isinstance(other, Lin):  # (called by name: `ref.__rsub__(x)` is x - ref)
            return other - self
        return Lin(other - self.a, -self.b, self.span)

    def _cmp(self, other: Any) -> int:
        if isinstance(other, Lin):
            return _sign(self.a - other.a, self.b - other.b, self.span)
        return _sign(self.a - other, self.b, self.span)

    def __lt__(self, other: Any) -> bool:
        return self._cmp(other) < 0

    def __le__(self, other: Any) -> bool:
        return self._cmp(other) <= 0

    def __gt__(self, other: Any) -> bool:
        return self._cmp(other) > 0

    def __ge__(self, other: Any) -> bool:
        return self._cmp(other) >= 0

    def __eq__(self, other: object) -> bool:
        return self._cmp(other) == 0

    def __ne__(self, other: object) -> bool:
        return self._cmp(other) != 0


def lifted(now: int, before: int, span: int) -> Lin:
    """A state value `now` that was `before` one period earlier, as a line over the stretch."""
    return Lin(now, now - before, span)


def parts(value: Any) -> tuple[int, int]:
    """(a, b) of a Lin, or of a plain number (b = 0)."""
    return (value.a, value.b) if isinstance(value, Lin) else (value, 0)


def continues(out: Any, start: Any) -> bool:
    """Whether a value after the period, `out`, is its start value `start` one step on: the
    same line moved by its own slope (a + b, b). A plain number is a line of slope 0."""
    (oa, ob), (sa, sb) = parts(out), parts(start)
    return ob == sb and oa == sa + sb


def drifts(value: Any) -> bool:
    """Whether a (nested) state holds a value that moves with j."""
    if isinstance(value, Lin):
        return value.b != 0
    if isinstance(value, (tuple, list)):
        return any(drifts(v) for v in value)
    return False


def solve(line: Any, value: Any, span: int) -> set[int] | None:
    """The j in 0..span at which the nested state `line` (Lin values in it) equals the plain
    state `value`: None for every j, else the set of such j (empty: never)."""
    if isinstance(line, Lin):
        if not isinstance(value, int) or isinstance(value, bool):
            return set()
        if line.b == 0:
            return None if line.a == value else set()
        j, left = divmod(value - line.a, line.b)
        return {j} if not left and 0 <= j <= span else set()
    if isinstance(line, (tuple, list)):
        if not isinstance(value, (tuple, list)) or len(line) != len(value):
            return set()
        out: set[int] | None = None
        for x, y in zip(line, value):
            js = solve(x, y, span)
            if js is None:
                continue
            out = js if out is None else out & js
            if not out:
                return out
        return out
    return None if line == value else set()
