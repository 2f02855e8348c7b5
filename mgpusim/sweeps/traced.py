"""Numbers that stand for one value per point: a program and model built once for many points.

Why: a grid over scene or schedule keys (``scene.width`` x ``scene.height``) makes every point
a program of its own, and building each program and its recurrence model in Python is most of
such a point (about 0.5 ms, where the lanes then run in microseconds). Most such keys only
move numbers (pixel counts, bytes) and not the program's structure, so the program is built
once with :class:`Traced` numbers in place of the values that differ between the points, and
the pass times, gaps and summary fields it yields are each a vector over the points.

How it stays exact:

- a :class:`Traced` holds the value of every point (plain Python values) and applies each
  arithmetic operation to each point's value with Python's own operators, so each element is
  what the point's own build computes;
- every use that would need one concrete value raises :class:`Untraceable` (``int()``,
  ``float()``, ``hash()``, text, indexing, iterating, any attribute): nothing leaks out as a
  constant. It is a BaseException, so no ``except Exception`` in the code built through turns
  it into another branch;
- a truth test (``if``, ``and``, ``min``, ``max``) whose answer differs between the points
  raises :class:`Split` with each point's answer, so that the caller builds each side apart;
  where every point answers the same, every point takes that branch, as its own build would;
- ``isinstance`` sees the points' own type (all of one type, else Untraceable);
- results equal at every point (same type, same value) become that plain value again.

:mod:`mgpusim.sweeps.lanes` builds the traced program and model for points whose loaded
experiments differ only in such numbers (checked per point, :func:`differences`), and checks
the first and last point against their own builds.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import math
import operator
import sys
from types import MappingProxyType
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

#: A path into a loaded experiment: attribute names, tuple indices, mapping keys.
Path = tuple


class Untraceable(BaseException):
    """A traced number was used where one concrete value is needed. `paths`: the inputs it
    came from; `values`: its value at each point, where one traced number was so used (the
    caller builds the points of each value apart), else None."""

    def __init__(self, what: str, paths: frozenset, values: list[Any] | None = None):
        super().__init__(what)
        self.paths, self.values = paths, values


class Split(BaseException):
    """A truth test answered differently at different points: `answers`, one per point."""

    def __init__(self, answers: list[bool], paths: frozenset):
        super().__init__("a branch differs between points")
        self.answers, self.paths = answers, paths


def _same(values: Sequence[Any]) -> bool:
    """Every value is the first, as far as any later use can tell (type, value, float sign)."""
    first = values[0]
    kind = type(first)
    if kind is float:
        text = repr(first)
        return all(type(v) is float and (v == first or v != v) and repr(v) == text for v in values)
    return all(type(v) is kind and v == first for v in values)


def make(values: list[Any], paths: frozenset) -> Any:
    """A Traced of `values`, or their one value where they are all the same."""
    return values[0] if _same(values) else Traced(values, paths)


def values_of(x: Any, n: int) -> list[Any]:
    """Each point's value: a Traced's own, a plain value `n` times."""
    return x.v if type(x) is Traced else [x] * n


def _binary(op: Callable[[Any, Any], Any], reflected: bool = False) -> Callable[[Any, Any], Any]:
    def method(self: "Traced", other: Any) -> Any:
        if type(other) is Traced:
            if len(other.v) != len(self.v):
                raise Untraceable("traced values of different points", self.paths | other.paths)
            pairs: Iterable[tuple[Any, Any]] = zip(other.v, self.v) if reflected else zip(self.v, other.v)
            return make([op(a, b) for a, b in pairs], self.paths | other.paths)
        if not _number(other):
            return NotImplemented
        if reflected:
            return make([op(other, a) for a in self.v], self.paths)
        return make([op(a, other) for a in self.v], self.paths)
    return method


def _unary(op: Callable[..., Any]) -> Callable[..., Any]:
    def method(self: "Traced", *args: Any) -> Any:
        if any(type(a) is Traced for a in args):
            raise Untraceable("a traced argument", self.paths)
        return make([op(a, *args) for a in self.v], self.paths)
    return method


_NUMBERS = (int, float, bool)


def _number(x: Any) -> bool:
    """A plain number a traced value may meet (int, float, bool, Fraction, numpy scalars)."""
    import numbers  # noqa: PLC0415

    return isinstance(x, _NUMBERS) or (type(x).__module__ in ("fractions", "numpy")
                                       and isinstance(x, numbers.Number))


def _refuse(what: str) -> Callable[..., Any]:
    def method(self: "Traced", *args: Any, **kwargs: Any) -> Any:
        raise Untraceable(what, self.paths, self.v)
    return method


class Traced:
    """One number per point (see the module doc)."""

    __slots__ = ("v", "paths")

    def __init__(self, values: list[Any], paths: frozenset):
        self.v, self.paths = values, paths

    @property  # type: ignore[misc]
    def __class__(self) -> type:  # noqa: D105 - isinstance() sees the points' type
        kind = type(self.v[0])
        if any(type(v) is not kind for v in self.v):
            raise Untraceable("values of several types", self.paths)
        return kind

    def __bool__(self) -> bool:
        answers = [bool(v) for v in self.v]
        if all(answers):
            return True
        if not any(answers):
            return False
        raise Split(answers, self.paths)

    def __copy__(self) -> "Traced":
        return self

    def __deepcopy__(self, memo: Any) -> "Traced":
        return self

    def __getattr__(self, name: str) -> Any:
        raise Untraceable(f"attribute {name}", object.__getattribute__(self, "paths"))

    __add__, __radd__ = _binary(operator.add), _binary(operator.add, True)
    __sub__, __rsub__ = _binary(operator.sub), _binary(operator.sub, True)
    __mul__, __rmul__ = _binary(operator.mul), _binary(operator.mul, True)
    __truediv__, __rtruediv__ = _binary(operator.truediv), _binary(operator.truediv, True)
    __floordiv__, __rfloordiv__ = _binary(operator.floordiv), _binary(operator.floordiv, True)
    __mod__, __rmod__ = _binary(operator.mod), _binary(operator.mod, True)
    __pow__, __rpow__ = _binary(operator.pow), _binary(operator.pow, True)
    __lt__, __le__ = _binary(operator.lt), _binary(operator.le)
    __gt__, __ge__ = _binary(operator.gt), _binary(operator.ge)
    __eq__, __ne__ = _binary(operator.eq), _binary(operator.ne)
    __and__, __rand__ = _binary(operator.and_), _binary(operator.and_, True)
    __or__, __ror__ = _binary(operator.or_), _binary(operator.or_, True)
    __neg__, __pos__, __abs__ = _unary(operator.neg), _unary(operator.pos), _unary(operator.abs)
    __floor__, __ceil__, __trunc__ = _unary(math.floor), _unary(math.ceil), _unary(math.trunc)
    __round__ = _unary(round)

    def __divmod__(self, other: Any) -> Any:
        return self // other, self % other

    def __rdivmod__(self, other: Any) -> Any:
        return other // self, other % self

    __hash__ = _refuse("hash")
    __index__ = _refuse("an integer index")
    __int__ = _refuse("int()")
    __float__ = _refuse("float()")
    __complex__ = _refuse("complex()")
    __str__ = _refuse("text")
    __repr__ = _refuse("text")
    __format__ = _refuse("text")
    __iter__ = _refuse("iteration")
    __len__ = _refuse("len()")
    __getitem__ = _refuse("indexing")
    __contains__ = _refuse("membership")
    __call__ = _refuse("a call")
    __reduce_ex__ = _refuse("pickling")
    __lshift__ = __rlshift__ = __rshift__ = __rrshift__ = __xor__ = __rxor__ = __invert__ = _refuse("bits")
    __matmul__ = __rmatmul__ = _refuse("@")


# ----- experiments as trees of numbers ---------------------------------------------------------

def differences(a: Any, b: Any, path: Path = (), out: dict | None = None) -> dict[Path, Any] | None:
    """{path: b's value} of every number where `b` differs from `a`, both trees of dataclasses,
    tuples, lists, dicts and mapping proxies; None if they differ otherwise (in shape, in a
    type, in anything not a number: the points are then not one program's numbers)."""
    out = {} if out is None else out
    return out if _diff(a, b, path, out) else None


def _diff(a: Any, b: Any, path: Path, out: dict) -> bool:
    if a is b:
        return True
    kind = type(a)
    if kind is not type(b):
        return False
    if kind is int:
        if a != b:
            out[path] = b
        return True
    if kind is str:
        return a == b
    if kind is float:
        if not _same([a, b]):
            out[path] = b
        return True
    if kind in (tuple, list):
        return len(a) == len(b) and all(_diff(x, y, (*path, i), out) for i, (x, y) in enumerate(zip(a, b)))
    if kind in (dict, MappingProxyType):
        return list(a) == list(b) and all(_diff(a[k], b[k], (*path, k), out) for k in a)
    if dataclasses.is_dataclass(a):
        names = list(vars(a)) if hasattr(a, "__dict__") else [f.name for f in dataclasses.fields(a)]
        if hasattr(b, "__dict__") and list(vars(b)) != names:
            return False
        return all(_diff(getattr(a, k), getattr(b, k), (*path, k), out) for k in names)
    try:
        return bool(a == b)
    except Exception:  # noqa: BLE001 - not comparable: not the same
        return False


def substituted(tree: Any, at: Mapping[Path, Any]) -> Any:
    """`tree` with the value at each path of `at` replaced (copies along the paths, the rest
    shared; a dataclass copied with its fields as they are, no constructor run again)."""
    if not at:
        return tree
    if () in at:
        return at[()]
    heads: dict[Any, dict[Path, Any]] = {}
    for p, v in at.items():
        heads.setdefault(p[0], {})[p[1:]] = v
    kind = type(tree)
    if kind in (tuple, list):
        items = list(tree)
        for i, sub in heads.items():
            items[i] = substituted(items[i], sub)
        return kind(items)
    if kind in (dict, MappingProxyType):
        d = dict(tree)
        for k, sub in heads.items():
            d[k] = substituted(d[k], sub)
        return d if kind is dict else MappingProxyType(d)
    new = copy.copy(tree)
    for name, sub in heads.items():
        object.__setattr__(new, name, substituted(getattr(tree, name), sub))
    return new


def traced_inputs(diffs: Sequence[Mapping[Path, Any]], probe: Any) -> dict[Path, Any]:
    """Per path any point's value differs at from the probe's, every point's value there (the
    probe's where the point's equals it): a Traced, or the one value they all have.
    `diffs[i]`: :func:`differences` of point i from the probe."""
    paths = sorted({p for d in diffs for p in d}, key=repr)
    out = {}
    for p in paths:
        base = _at(probe, p)
        out[p] = make([d.get(p, base) for d in diffs], frozenset([p]))
    return out


def _at(tree: Any, path: Path) -> Any:
    for step in path:
        tree = tree[step] if isinstance(tree, (tuple, list, dict, MappingProxyType)) else getattr(tree, step)
    return tree


# ----- int() and float() of a traced number --------------------------------------------------
class _Conversion(type):
    """`int` and `float` as the modules built through see them while a trace runs: the type
    itself for every plain value and isinstance() check, each point's conversion for a Traced
    (Python itself makes int() and float() return a plain int or float)."""

    real: type

    def __instancecheck__(cls, x: Any) -> bool:
        return isinstance(x, cls.real)

    def __subclasscheck__(cls, sub: type) -> bool:
        return issubclass(sub, cls.real)

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        if args and type(args[0]) is Traced:
            if len(args) > 1 or kwargs or any(type(a) is Traced for a in args[1:]):
                raise Untraceable(f"{cls.real.__name__}() of a traced value with options", args[0].paths)
            return make([cls.real(v) for v in args[0].v], args[0].paths)
        return cls.real(*args, **kwargs)


class _Int(metaclass=_Conversion):
    real = int


class _Float(metaclass=_Conversion):
    real = float


@contextlib.contextmanager
def conversions(prefix: str = "mgpusim.") -> Iterator[None]:
    """While a trace runs: `int` and `float` in the globals of every module under `prefix`
    (but the sweep's own, :mod:`mgpusim.sweeps`) are :class:`_Conversion` types, so that
    ``int(x)`` and ``float(x)`` of a Traced are each point's conversion; each module's own
    names are as they were afterwards.
    (The sweep runs its points in one thread.) A module that compared ``type(x) is int``
    would find it False for plain ints meanwhile: the modules a trace builds through use
    isinstance() instead."""
    patched: list[tuple[dict, str, Any]] = []
    missing = object()
    try:
        for name, module in list(sys.modules.items()):
            if not name.startswith(prefix) or name.startswith(__package__ + ".") or module is None:
                continue
            space = module.__dict__
            for key, shadow in (("int", _Int), ("float", _Float)):
                patched.append((space, key, space.get(key, missing)))
                space[key] = shadow
        yield
    finally:
        for space, key, old in reversed(patched):
            if old is missing:
                space.pop(key, None)
            else:
                space[key] = old
