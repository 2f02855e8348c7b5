"""`--set key=value` overrides: dotted keys applied to a raw TOML table before validation, so
an override is checked exactly like the same value written in the file.

Keys under ``profile.`` change the experiment's hardware profile (hardware what-ifs, e.g.
``profile.gpus.0.link.pcie_gen=5``); every other key changes the experiment itself.
"""
from __future__ import annotations

import tomllib
from typing import Any, Mapping

from mgpusim.model.errors import InputError

PROFILE_PREFIX = "profile."
#: Dotted parts of one key: the deepest table of a profile is four levels down.
MAX_DEPTH = 16


def parse_value(text: str) -> Any:
    """A --set value as TOML (numbers, booleans, quoted strings, lists, inline tables); bare
    words as strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:  # tomllib recurses once per level of nested arrays and tables
        raise InputError(f"the value {text[:40]!r}... is nested too deeply", field="--set") from None


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """`--set` arguments as {dotted key: value}; a missing '=' or an empty key part is refused
    here, naming the argument."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"expects key=value, got {item!r}", field="--set")
        key, _, text = item.partition("=")
        key = key.strip()
        if not key:
            raise InputError(f"{item!r} has no key before '=' (e.g. schedule.gpus=3)", field="--set")
        if any(not part.strip() for part in key.split(".")):
            raise InputError(f"{item!r}: the key {key!r} has an empty part between dots",
                             field="--set")
        out[key] = parse_value(text.strip())
    return out


def split_profile(overrides: Mapping[str, Any] | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(experiment overrides, profile overrides with the ``profile.`` prefix removed)."""
    experiment, profile = {}, {}
    for key, value in (overrides or {}).items():
        if key.startswith(PROFILE_PREFIX):
            profile[key.removeprefix(PROFILE_PREFIX)] = value
        else:
            experiment[key] = value
    return experiment, profile


def set_dotted(data: dict, key: str, value: Any, file: str, prefix: str = "") -> None:
    """Set `key` (dotted) in `data`. A number indexes an array of tables
    (``scene.passes.0.iterations``) and ``*`` stands for every entry of one
    (``gpus.*.speed``); missing tables are created. `prefix` is how the user wrote the key's
    start (``profile.``), for messages."""
    parts = key.split(".")
    if len(parts) > MAX_DEPTH:
        raise InputError(f"cannot set {prefix + key[:60]!r}...: more than {MAX_DEPTH} dotted parts",
                         file=file, field="--set")
    _set(data, parts, value, file, prefix + key, 0)


def _set(node: Any, parts: list[str], value: Any, file: str, shown: str, depth: int) -> None:
    part, last = parts[depth], depth == len(parts) - 1
    if isinstance(node, list):
        indices = range(len(node)) if part == "*" else (_index(node, part, shown, file),)
        for i in indices:
            if last:
                node[i] = value
            else:
                _set(_container(node[i], parts, depth, shown, file), parts, value, file, shown, depth + 1)
        return
    if last:
        node[part] = value
        return
    _set(_container(node.setdefault(part, {}), parts, depth, shown, file), parts, value, file,
         shown, depth + 1)


def _container(child: Any, parts: list[str], depth: int, shown: str, file: str) -> Any:
    if not isinstance(child, (dict, list)):
        raise InputError(f"cannot set {shown!r}: {'.'.join(parts[:depth + 1])} is not a table",
                         file=file, field=shown)
    return child


def _index(items: list, part: str, shown: str, file: str) -> int:
    if not (part.isascii() and part.isdigit()) or int(part) >= len(items):
        raise InputError(f"cannot set {shown!r}: {part!r} is not an index below {len(items)} "
                         "(or '*' for all)", file=file, field=shown)
    return int(part)
