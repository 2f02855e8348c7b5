"""Reading TOML tables with validation: every error names the file and the dotted field.

Used by the profile and experiment loaders so that bad input stops before time 0 with one
clear message (missing field, wrong type, out-of-range value, unknown key).
"""
from __future__ import annotations

import copy
import difflib
import math
import tomllib
from pathlib import Path
from typing import Any, Iterable

from mgpusim.model.errors import InputError
from mgpusim.model.limits import MAX_INPUT_FILE_BYTES, MAX_NAME_BYTES

_MISSING = object()
_TYPE_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "true or false",
               list: "a list", dict: "a table"}


#: The most parsed files :func:`read_toml` keeps, by their bytes, and the largest it keeps (a
#: generated frame of 10^5 passes is parsed each time rather than held).
PARSED_KEPT = 128
PARSED_MAX_BYTES = 1 << 20
_PARSED: dict[bytes, dict[str, Any]] = {}


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable, empty, binary, oversized, too deeply nested
    or malformed file is one InputError naming it. A UTF-8 byte-order mark (which some
    editors write) is skipped. The file is read every time; the same bytes are parsed once
    (a copy of the tables is returned, which the caller may change). Why: a search loads one
    experiment and one profile file hundreds of times, and parsing cost more than the rest of
    loading."""
    raw = read_input_bytes(Path(path), "a TOML file")
    if len(raw) > PARSED_MAX_BYTES:
        return _parse(raw, str(path))
    parsed = _PARSED.get(raw)
    if parsed is None:
        parsed = _parse(raw, str(path))
        if len(_PARSED) >= PARSED_KEPT:
            _PARSED.pop(next(iter(_PARSED)))
        _PARSED[raw] = parsed
    return copy.deepcopy(parsed)


def _parse(raw: bytes, file: str) -> dict[str, Any]:
    """The tables of a TOML file's bytes (see :func:`read_toml`)."""
    if not raw.strip():
        raise InputError("the file is empty, expected TOML", file=file)
    if b"\0" in raw:
        raise InputError("a binary file, expected TOML text", file=file)
    try:
        text = raw.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}), expected TOML", file=file) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML ({exc})", file=file) from None
    except RecursionError:  # tomllib recurses once per level of nested arrays and tables
        raise InputError("not valid TOML here: arrays or tables nested too deeply", file=file) from None


def read_input_bytes(path: Path, expected: str, limit: int = MAX_INPUT_FILE_BYTES) -> bytes:
    """The bytes of an input file, read up to `limit`: a missing file, a folder, an unreadable
    one, or an endless or huge one (/dev/zero, a disk image) is one InputError."""
    file = str(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(limit + 1)
    except FileNotFoundError:
        raise InputError("file not found", file=file) from None
    except IsADirectoryError:
        raise InputError(f"is a folder, expected {expected}", file=file) from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the name
        raise InputError(f"cannot read the file ({getattr(exc, 'strerror', None) or exc})",
                         file=file) from None
    if len(raw) > limit:
        size = "a few KB" if limit == MAX_INPUT_FILE_BYTES else f"at most {limit >> 20} MiB"
        raise InputError(f"larger than {limit >> 20} MiB (or endless), expected {expected} of "
                         f"{size}", file=file)
    return raw


def name_problem(name: str) -> str | None:
    """Why `name` cannot be one file or folder name inside an output folder, or None. Why:
    configuration, experiment and study names become folder names (`runs/<name>`,
    `out/<name>`); a name with a separator, `..` or a NUL would write elsewhere or fail late."""
    if not name.strip():
        return "is empty"
    if "\0" in name:
        return "holds a NUL character"
    if "/" in name or "\\" in name:
        return "holds a path separator ('/' or '\\')"
    if name in (".", ".."):
        return f"is {name!r}"
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        return "holds a control character"
    if len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        return f"is longer than {MAX_NAME_BYTES} bytes"
    return None


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """' (did you mean 'x'?)' for the closest known word, or '' when none is close."""
    close = difflib.get_close_matches(word, sorted(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class Table:
    """A view of one TOML table that hands out validated fields and rejects unknown keys."""

    def __init__(self, data: Any, file: str, path: str = ""):
        if not isinstance(data, dict):
            raise InputError("expected a table", file=file, field=path or "<top>")
        self.data, self.file, self.path = data, file, path
        self._used: set[str] = set()

    def field(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, message: str) -> InputError:
        return InputError(message, file=self.file, field=self.field(key))

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, kind: type, default: Any = _MISSING, *, minimum: float | None = None,
            above: float | None = None, maximum: float | None = None, why: str = "",
            choices: Iterable[Any] | None = None) -> Any:
        """The value at `key`, checked for type and range; `default` if absent (else an error).

        Numbers must be finite; `maximum` is an upper bound that keeps simulated time and
        allocations in range, `why` says which (it goes into the message with the bound)."""
        self._used.add(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(key, f"missing (expected {_TYPE_NAMES[kind]})")
            return default
        value = self.data[key]
        value = _coerce(value, kind)
        if value is None:
            raise self.error(key, f"expected {_TYPE_NAMES[kind]}, got {show_value(self.data[key])}")
        if kind is float and not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {show_value(self.data[key])}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {show_value(value)}")
        if above is not None and value <= above:
            raise self.error(key, f"must be > {above}, got {show_value(value)}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be <= {maximum:g}{f' ({why})' if why else ''}, got {show_value(value)}")
        if choices is not None and value not in tuple(choices):
            raise self.error(key, f"must be one of {sorted(choices)}, got {show_value(value)}"
                             + (did_you_mean(value, choices) if isinstance(value, str) else ""))
        return value

    def name(self, key: str, default: Any = _MISSING) -> Any:
        """A string that must serve as one file or folder name (see :func:`name_problem`)."""
        value = self.get(key, str, default)
        problem = name_problem(value) if isinstance(value, str) else None
        if problem:
            raise self.error(key, f"must be a plain file name (it names a folder of the output), "
                                  f"but {show_value(value)} {problem}")
        return value

    def table(self, key: str, default: Any = _MISSING) -> "Table":
        self._used.add(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(key, "missing table")
            return Table({} if default is None else default, self.file, self.field(key))
        return Table(self.data[key], self.file, self.field(key))

    def tables(self, key: str) -> list["Table"]:
        """An array of tables ([[key]]), each a Table with an indexed path."""
        self._used.add(key)
        items = self.data.get(key)
        if not isinstance(items, list) or not items:
            raise self.error(key, "missing or empty array of tables")
        return [Table(item, self.file, f"{self.field(key)}[{i}]") for i, item in enumerate(items)]

    def rest(self) -> dict[str, Any]:
        """Keys not read yet (for tables whose keys are open, like cost coefficients)."""
        return {k: v for k, v in self.data.items() if k not in self._used}

    def finish(self) -> None:
        """Reject keys that were never read: a typo must not be silently ignored."""
        unknown = sorted(set(self.data) - self._used)
        if unknown:
            raise self.error(unknown[0], "unknown key" + did_you_mean(unknown[0], self._used))


def int_list(text: str | None, field: str) -> list[int] | None:
    """A command-line list like "0,1" (None when not given); bad items are one InputError."""
    if not text:
        return None
    try:
        return [int(t) for t in text.split(",")]
    except ValueError:
        raise InputError(f"expected comma-separated integers, got {text!r}", field=field) from None


def show_value(value: Any, limit: int = 60) -> str:
    """A value for a message, cut short: a fuzzed 10 MB string must not become the message."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _coerce(value: Any, kind: type) -> Any:
    if kind is float:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return None
        try:
            return float(value)
        except OverflowError:  # an integer beyond a double: reported as not finite
            return math.inf
    if kind is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else None
    return value if isinstance(value, kind) else None
