"""A Chrome trace's JSON read event by event: each element of its event list is decoded and
handed to the caller, which keeps what it needs, before the next is decoded.

Why not `json.loads`: a capture of 10^6 events decodes to 10^6 dicts (with their `args`
dicts and lists), about 1 KB each, which is more memory than the capture and the import
together need. Decoding one event at a time keeps only the text and what the caller keeps.
The file is read through the checked byte reader (size bound, unreadable files), and a text
that is not JSON is the same one InputError `mgpusim.io.table_files.parse_json` gives: "not
valid JSON (...)" with json's own line and column, or "nested too deeply".
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Callable

from mgpusim.model.errors import InputError
from mgpusim.model.toml_checks import read_input_bytes

_WS = re.compile(r"[ \t\n\r]*")
_DECODER = json.JSONDecoder()
#: The top-level key of the event list.
EVENTS_KEY = "traceEvents"


def read_text(path: Path, expected: str, limit: int) -> str:
    """The file's text (UTF-8, a byte-order mark dropped), at most `limit` bytes."""
    file = str(path)
    try:
        if path.is_dir():
            raise InputError(f"is a folder, expected {expected}", file=file)
        if not path.is_file():
            raise InputError(f"not found (or not a file), expected {expected}", file=file)
    except OSError as exc:  # a name too long, a loop of links
        raise InputError(f"cannot open ({exc.strerror or exc})", file=file) from None
    raw = read_input_bytes(path, expected, limit)
    try:
        return raw.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start}), expected {expected}", file=file) from None


def stream_events(text: str, file: str, consume: Callable[[Any, int], None]) -> dict[str, Any] | None:
    """Decode `text` (a list of events, or an object with a `traceEvents` list), calling
    `consume(event, i)` for each event in order; returns the object's other keys (None for a
    bare list)."""
    try:
        return _document(text, file, consume)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON ({str(exc).splitlines()[0][:160]})", file=file) from None
    except RecursionError:
        raise InputError("not valid JSON here: nested too deeply", file=file) from None


def _document(text: str, file: str, consume: Callable[[Any, int], None]) -> dict[str, Any] | None:
    i = _WS.match(text).end()  # type: ignore[union-attr]  # matches the empty string
    top: dict[str, Any] | None = None
    if text.startswith("[", i):
        i = _events(text, i, consume)
    elif text.startswith("{", i):
        top, i = _object(text, i, file, consume)
    else:
        value, i = _DECODER.raw_decode(text, i)  # a number, a string, or not JSON at all
        raise InputError(f"expected a list of events or an object with a {EVENTS_KEY} list, got "
                         f"{type(value).__name__}", file=file, field=EVENTS_KEY)
    i = _WS.match(text, i).end()  # type: ignore[union-attr]
    if i != len(text):
        raise json.JSONDecodeError("Extra data", text, i)
    return top


def _events(text: str, i: int, consume: Callable[[Any, int], None]) -> int:
    """The list starting at text[i] ('['), each element to `consume`; returns the index past it."""
    i = _WS.match(text, i + 1).end()  # type: ignore[union-attr]
    if text.startswith("]", i):
        return i + 1
    n = 0
    scan = _DECODER.scan_once  # type: ignore[attr-defined]  # raw_decode's scanner, unwrapped (10^6 calls)
    while True:
        try:
            value, i = scan(text, i)
        except StopIteration as err:
            raise json.JSONDecodeError("Expecting value", text, err.value) from None
        consume(value, n)
        n += 1
        i = _WS.match(text, i).end()  # type: ignore[union-attr]
        if text.startswith(",", i):
            i = _WS.match(text, i + 1).end()  # type: ignore[union-attr]
        elif text.startswith("]", i):
            return i + 1
        else:
            raise json.JSONDecodeError("Expecting ',' delimiter", text, i)


def _object(text: str, i: int, file: str, consume: Callable[[Any, int], None]) -> tuple[dict[str, Any], int]:
    """The top-level object at text[i] ('{'): its `traceEvents` list streamed, the rest kept."""
    out: dict[str, Any] = {}
    seen = False
    i = _WS.match(text, i + 1).end()  # type: ignore[union-attr]
    if text.startswith("}", i):
        i += 1
    else:
        while True:
            key, i = _key(text, i)
            if key == EVENTS_KEY and text.startswith("[", i):
                if seen:
                    raise InputError(f"{EVENTS_KEY} given twice", file=file, field=EVENTS_KEY)
                seen, i = True, _events(text, i, consume)
            else:
                out[key], i = _DECODER.raw_decode(text, i)
            i = _WS.match(text, i).end()  # type: ignore[union-attr]
            if text.startswith(",", i):
                i = _WS.match(text, i + 1).end()  # type: ignore[union-attr]
            elif text.startswith("}", i):
                i += 1
                break
            else:
                raise json.JSONDecodeError("Expecting ',' delimiter", text, i)
    if not seen:
        raise InputError(f"expected a list of events or an object with a {EVENTS_KEY} list",
                         file=file, field=EVENTS_KEY)
    return out, i


def _key(text: str, i: int) -> tuple[str, int]:
    """A member's key at text[i] and the index of its value (past the ':')."""
    if not text.startswith('"', i):
        raise json.JSONDecodeError("Expecting property name enclosed in double quotes", text, i)
    key, i = _DECODER.raw_decode(text, i)
    i = _WS.match(text, i).end()  # type: ignore[union-attr]
    if not text.startswith(":", i):
        raise json.JSONDecodeError("Expecting ':' delimiter", text, i)
    return key, _WS.match(text, i + 1).end()  # type: ignore[union-attr]
