"""A RenderDoc capture (`.rdc`) read into the slice table: its frame's passes timed by replay.

RenderDoc (https://renderdoc.org) captures one frame of a Vulkan, D3D or OpenGL program: its API
calls and resources, no times. GPU times come from replaying the frame: RenderDoc times each
action (draw, dispatch, copy, clear) alone with its `GPU Duration` counter, on the GPU that
replays it (https://renderdoc.org/docs/window/performance_counter_viewer.html). The replay
runs in a child process (:mod:`.rdc_replay`, which needs RenderDoc's Python module); this
module turns its record into slices, which needs nothing of RenderDoc.

A pass is what an engine labels one: the actions under one debug marker (vkCmdBeginDebugUtilsLabelEXT,
PIXBeginEvent, glPushDebugGroup), the innermost where markers nest, consecutive actions of one
marker being one pass; actions under no marker are grouped by render pass (`Render pass k`),
others each on its own. Its time is the sum of its actions' durations; each replay is one
frame of the table, so the import's median and spread are over the replays. What a pass writes
(colour and depth targets, storage, a copy's destination) and reads (textures, storage and
vertex buffers, a copy's source) are resources by RenderDoc's names, with their bytes. The
frame's size is its swapchain image's, else the last pass's colour target's.
"""
from __future__ import annotations

import json
import math
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from mgpusim.frames import rdc_replay
from mgpusim.model.errors import InputError

#: How many times the frame is replayed (each a frame of the slice table: the median and spread
#: are over them).
REPLAYS = 5
#: The longest replay waited for (a capture of a large frame on a slow software GPU).
REPLAY_TIMEOUT_S = 600
#: The first bytes of every RenderDoc capture.
MAGIC = b"RDOC"
#: The largest capture read (RenderDoc's captures of a game's frame run to hundreds of MiB).
MAX_RDC_BYTES = 4 << 30


def read_rows(path: Path, replays: int = REPLAYS) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The capture's slices (rows of :data:`mgpusim.frames.formats.SLICE_COLUMNS`) over
    `replays` replays, and what it says (size, notes)."""
    check_capture(path)
    return rows_from_record(replay_record(path, replays), str(path))


def check_capture(path: Path) -> None:
    """A readable file that starts as a RenderDoc capture: anything else is refused here,
    without starting RenderDoc."""
    file = str(path)
    try:
        if path.is_dir():
            raise InputError("is a folder, expected a RenderDoc capture (.rdc)", file=file)
        if not path.is_file():
            raise InputError("not found (or not a file), expected a RenderDoc capture (.rdc)", file=file)
    except OSError as exc:
        raise InputError(f"cannot open ({exc.strerror or exc})", file=file) from None
    try:
        with path.open("rb") as f:
            head = f.read(len(MAGIC))
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=file) from None
    if head != MAGIC:
        raise InputError(f"not a RenderDoc capture (it does not start with {MAGIC.decode()})", file=file)
    if path.stat().st_size > MAX_RDC_BYTES:
        raise InputError(f"larger than {MAX_RDC_BYTES >> 30} GiB, the largest RenderDoc capture read", file=file)


def replay_record(path: Path, replays: int = REPLAYS) -> dict[str, Any]:
    """The child's record of the capture's replay (:mod:`.rdc_replay`); one InputError naming
    the file where RenderDoc is missing, refuses the file or fails."""
    file = str(path)
    cmd = [sys.executable, "-m", rdc_replay.__name__, str(path.resolve()), str(replays)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=REPLAY_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        raise InputError(f"RenderDoc's replay took longer than {REPLAY_TIMEOUT_S} s", file=file) from None
    lines = done.stdout.strip().splitlines()
    try:
        record = json.loads(lines[-1]) if lines else None  # text, not a file: the child's stdout
    except json.JSONDecodeError:
        record = None
    if done.returncode == rdc_replay.FAILED and isinstance(record, dict) and "error" in record:
        raise InputError(_one_line(str(record["error"])) + _install_hint(str(record["error"])), file=file)
    if done.returncode != 0 or not isinstance(record, dict):
        how = f"signal {-done.returncode}" if done.returncode < 0 else f"status {done.returncode}"
        last = _one_line(done.stderr.strip().splitlines()[-1]) if done.stderr.strip() else "no message"
        raise InputError(f"RenderDoc's replay of the capture failed ({how}: {last})", file=file)
    return record


def _one_line(text: str) -> str:
    return " ".join(text.split())[:300]


def _install_hint(error: str) -> str:
    return ("; install it (Debian/Ubuntu: apt-get install python3-renderdoc) or set RENDERDOC_PYTHON_PATH "
            "to the folder holding RenderDoc's renderdoc.so") if "renderdoc.so" in error else ""


def rows_from_record(record: dict[str, Any], file: str) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The replay's record (:mod:`.rdc_replay`) as slices: one row per pass and replay."""
    actions, resources = record.get("actions"), record.get("resources")
    if not isinstance(actions, list) or not isinstance(resources, dict):
        raise InputError("RenderDoc's replay gave no actions", file=file)
    if not actions:
        raise InputError("the capture's frame has no GPU work (no draw, dispatch, copy or clear)", file=file)
    passes = _passes(actions)
    replays = len(actions[0]["seconds"])
    # what a pass reads, writes and its bytes are the same in every replay: only its time is not
    known = [(name, group, _names(group, "reads", resources, exclude="writes"),
              _names(group, "writes", resources), _bytes(_ids(group, "writes"), resources))
             for name, group in passes]
    rows = []
    for frame in range(replays):
        for name, group, reads, writes, nbytes in known:
            rows.append({"frame": frame, "queue": "graphics", "name": name,
                         "ms": sum(a["seconds"][frame] for a in group) * 1000.0,
                         "start_ns": math.nan, "end_ns": math.nan, "reads": reads, "writes": writes,
                         "bytes": nbytes, "view": -1, "pixel_share": math.nan})
    meta: dict[str, Any] = {"left_out": {}, "notes": [_replay_note(record, len(passes))],
                            "frames_are": "replay(s) of its one frame", **_size(passes, resources)}
    return rows, meta


def _passes(actions: list[dict[str, Any]]) -> list[tuple[str, list[dict[str, Any]]]]:
    """Consecutive actions of one pass (see the module doc), named."""
    out: list[tuple[str, list[dict[str, Any]]]] = []
    last: Any = None
    for a in actions:
        markers, rp = a.get("markers") or [], a.get("render_pass", -1)
        key = ("marker", tuple(markers)) if markers else ("pass", rp) if rp >= 0 else ("action", a["event"])
        if key != last:
            name = markers[-1] if markers else f"Render pass {rp}" if rp >= 0 else \
                f"{a['name']} (event {a['event']})"
            out.append((name.strip() or "(unnamed)", []))
            last = key
        out[-1][1].append(a)
    return out


def _ids(group: list[dict[str, Any]], key: str) -> list[int]:
    """The resources the pass's actions list under `key`, each once, in order."""
    return list(dict.fromkeys(r for a in group for r in a.get(key, [])))


def _names(group: list[dict[str, Any]], key: str, resources: dict[str, Any], exclude: str = "") -> tuple[str, ...]:
    """Resource names of `key` (for reads: not what the pass itself wrote before)."""
    skip = set(_ids(group, exclude)) if exclude else set()
    return tuple(_resource_name(r, resources) for r in _ids(group, key) if r not in skip)


def _bytes(ids: list[int], resources: dict[str, Any]) -> tuple[int, ...]:
    """Each written resource's bytes, where RenderDoc knows them all (else none: the import
    takes a colour target of the frame)."""
    sizes = [resources.get(str(r), {}).get("bytes") for r in ids]
    return tuple(int(b) for b in sizes) if all(isinstance(b, int) for b in sizes) else ()


def _resource_name(rid: int, resources: dict[str, Any]) -> str:
    found = resources.get(str(rid))
    return str(found["name"]) if isinstance(found, dict) and found.get("name") else f"resource {rid}"


def _size(passes: list[tuple[str, list[dict[str, Any]]]], resources: dict[str, Any]) -> dict[str, int]:
    """The frame's resolution: the swapchain image a pass draws into, else the last pass's
    colour target (the first texture of the last pass that writes one: an action lists its
    colour targets first)."""
    textures = {int(k): v for k, v in resources.items() if isinstance(v, dict) and "width" in v}
    written = [r for _, group in passes for r in _ids(group, "writes") if r in textures]
    swap = [r for r in written if textures[r].get("swapchain")]
    for rid in swap[-1:] or [r for _, g in reversed(passes) for r in _ids(g, "writes") if r in textures][:1]:
        return {"width": int(textures[rid]["width"]), "height": int(textures[rid]["height"])}
    return {}


def _replay_note(record: dict[str, Any], passes: int) -> str:
    frame = record.get("frame")
    what = f"frame {frame}" if frame is not None else "its frame"
    replays = len(record["actions"][0]["seconds"])
    per_replay = statistics.median(sum(a["seconds"][r] for a in record["actions"]) for r in range(replays)) * 1e3
    return (f"a {record.get('api', '')} capture by {record.get('tool', 'RenderDoc')}: {what} replayed {replays} "
            f"time(s) on {record.get('replay_gpu') or 'this machine'}, {passes} pass(es), {per_replay:.3f} ms of GPU "
            "time in the median replay; each pass is the sum of its actions' GPU Duration (RenderDoc times each action "
            "alone, in order), its median over the replays: times of the replaying GPU, not the captured run")
