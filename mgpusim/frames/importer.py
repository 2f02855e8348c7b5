"""A measured frame as an experiment: `mgpusim frame import`.

A capture's slices (:mod:`mgpusim.frames.formats`) become one frame: every pass with
its median GPU time over the captured frames, the queue it ran on, the passes whose outputs it
reads and the bytes of its output that others read, the CPU work per frame. The frame is
written as an experiment of `captured` passes (docs/formats.md) that every schedule can run,
so `mgpusim simulate`, `sweep` and `advise` take it like any other experiment.

How a pass's output is found: a pass reads resources (names); the last pass before it in the
frame that writes a resource is its producer. A resource written only at or after the reader
is the previous frame's (a temporal input, which alternate-frame rendering must carry between
GPUs). A name that no pass writes but that is a pass's name means all that pass writes; other
names (textures loaded once, buffers from the CPU) are no pass's. A pass's `output_bytes` is the
size of what it writes that another pass reads (where the capture gives no size: a colour
target of the frame, which the import notes), and the last pass's image is presented.
"""
from __future__ import annotations

import bisect
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, cast

import numpy as np
import pandas as pd

from mgpusim.frames.shares import INFERRED, OPTION, STATED, Share, infer_share, share_comment
from mgpusim.model.errors import InputError
from mgpusim.schedules.experiment import Experiment, parse_experiment

#: Bytes per pixel of the colour target assumed for an output the capture gives no size for.
DEFAULT_COLOR_BYTES = 4


@dataclass(frozen=True)
class CapturedPass:
    """One pass of the frame: median `gpu_ms` over the `frames` it ran in."""

    name: str
    queue: str
    gpu_ms: float
    frames: int
    pixel_share: float
    reads: tuple[str, ...] = ()
    output_bytes: int = 0
    #: the spread of its time over the frames (median absolute deviation, ms)
    spread_ms: float = 0.0
    #: where its pixel share came from (the capture, --pixel-share, inferred) and why
    share: Share | None = None
    #: what it ran (median, ms) where that is more than `gpu_ms`: a compute-queue pass that
    #: overlapped graphics work, whose `gpu_ms` is only what it added to the frame
    ran_ms: float | None = None


@dataclass(frozen=True)
class CapturedFrame:
    """A frame from a capture: its passes in order (one eye's, for a stereo frame), the CPU
    work per frame, and what the import noticed and left out (`notes`)."""

    name: str
    source: str
    width: int
    height: int
    passes: tuple[CapturedPass, ...]
    frames: int
    cpu_ms: float = 0.0
    views: int = 1
    #: the GPU's busy span per frame (median of last end - first start), where times are known
    gpu_span_ms: float | None = None
    notes: tuple[str, ...] = ()
    #: where a measured run came from (experiment name and file, schedule)
    origin: Mapping[str, Any] = field(default_factory=dict)
    #: what its `frames` are: frames of the capture, or replays of its one frame (RenderDoc)
    frames_are: str = "captured frame(s)"

    @property
    def gpu_ms(self) -> float:
        """The sum of the passes' times (one eye's for a stereo frame)."""
        return sum(p.gpu_ms for p in self.passes)


def frame_from_slices(slices: pd.DataFrame, *, name: str, source: str, width: int, height: int,
                      pixel_share: float | None = None, left_out: Mapping[str, float] | None = None,
                      origin: Mapping[str, Any] | None = None,
                      share_why: Mapping[str, str] | None = None, read_notes: Sequence[str] = (),
                      frames_are: str = "captured frame(s)") -> CapturedFrame:
    """The frame the slices make (see the module doc); `pixel_share` for passes whose capture
    does not say how much of their time scales with pixels (None: inferred from the pass,
    :mod:`mgpusim.frames.shares`); `share_why`: why the capture states a pass's share, where it
    says (a measured run's pass kinds); `read_notes`: what the reader noted (which run of a
    study's folder, where a multi-GPU run's passes ran), first among the frame's notes;
    `frames_are`: what the capture's frames are (a RenderDoc capture's: replays of its one frame)."""
    gpu = slices[slices["queue"].isin(["graphics", "compute"])]
    if gpu.empty:
        raise InputError("no GPU passes in the capture (queues graphics or compute)", file=source)
    frames = sorted(gpu["frame"].unique())
    views = 2 if (gpu["view"] >= 0).any() else 1
    if views == 2 and (gpu["view"] < 0).any():
        bad = gpu.loc[gpu["view"] < 0, "name"].iloc[0]
        raise InputError(f"a stereo capture (passes with a view) where pass {bad!r} has none: give "
                         "every GPU pass its view (0 or 1)", file=source, field="view")
    gpu = exposed_times(gpu)
    keyed = _occurrences(gpu)
    if views == 2:
        _check_views(keyed, source)
    passes = _passes(keyed, pixel_share, width * height, share_why or {})
    notes = list(read_notes) + _notes(slices, keyed, passes, len(frames), left_out or {}, views)
    cpu = slices[slices["queue"] == "cpu"]
    cpu_ms = float(cpu["ms"].sum()) / len(frames) if len(cpu) else 0.0
    span = _gpu_span(gpu)
    if span is not None and views == 1 and span < 0.95 * sum(p.gpu_ms for p in passes[0]):
        notes.append(f"passes overlapped in the capture: the GPU was busy {span:.3f} ms per frame, "
                     f"the passes sum to {sum(p.gpu_ms for p in passes[0]):.3f} ms; the schedules "
                     "run them one after the other")
    return CapturedFrame(name, source, width, height, passes[0], len(frames), cpu_ms, views, span,
                         tuple(notes + list(passes[1])), dict(origin or {}), frames_are)


def _occurrences(gpu: pd.DataFrame) -> pd.DataFrame:
    """Each slice keyed by its pass: its name, with '#k' for the k-th slice of that name in its
    frame and view (a pass run twice a frame is two passes; where the capture has a pass named
    so already, '#k_2', '#k_3', ...), and its start within its frame."""
    df = gpu.copy()
    df["order"] = range(len(df))
    df = df.sort_values(["frame", "view", "start_ns", "order"], kind="stable", na_position="last")
    nth = df.groupby(["frame", "view", "name"], sort=False).cumcount()
    df["key"] = df["name"]
    again = nth > 0
    if again.any():
        pairs = pd.DataFrame({"name": df["name"][again], "nth": nth[again]})
        first = pairs.drop_duplicates()
        keys = _repeat_keys(list(zip(first["name"], first["nth"])), set(df["name"]))
        df.loc[again, "key"] = [keys[p] for p in zip(pairs["name"], pairs["nth"])]
    first_start = df.groupby(["frame", "view"], sort=False)["start_ns"].transform("min")
    df["offset"] = df["start_ns"] - first_start
    return df


def _repeat_keys(pairs: list[tuple[str, int]], taken: set[str]) -> dict[tuple[str, int], str]:
    """The key of the (nth + 1)-th slice of a name, for each (name, nth) in order of first
    appearance: `name#k`, made unique against the capture's names and the keys before it."""
    taken = set(taken)
    out = {}
    for name, nth in pairs:
        base = key = f"{name}#{nth + 1}"
        j = 2
        while key in taken:
            key, j = f"{base}_{j}", j + 1
        taken.add(key)
        out[(name, nth)] = key
    return out


def _check_views(keyed: pd.DataFrame, source: str) -> None:
    """A stereo capture has both views, and each view of a frame the same passes: what the
    schedule runs once per eye (an uneven capture would be run as if both eyes had the
    passes of either)."""
    seen = set(keyed["view"].unique())
    if seen != {0, 1}:
        raise InputError(f"a stereo capture with only view {min(seen)}: give both views (0 and 1, left and "
                         "right), or no view for a one-view frame", file=source, field="view")
    by_view = {v: set(zip(g["frame"], g["key"])) for v, g in keyed.groupby("view")}
    odd = sorted(by_view[0] ^ by_view[1], key=str)
    if odd:
        frame, key = odd[0]
        has = 0 if (frame, key) in by_view[0] else 1
        raise InputError(f"pass {key!r} of frame {frame} is in view {has} but not in view {1 - has}: a "
                         "stereo capture gives each eye the same passes", file=source, field="view")


def _passes(keyed: pd.DataFrame, default_share: float | None, pixels: int,
            share_why: Mapping[str, str]) -> tuple[tuple[CapturedPass, ...], list[str]]:
    """The passes in frame order, their reads resolved to passes, each one's pixel share and
    where it came from, and notes on assumed sizes."""
    by_key = keyed.groupby("key", sort=False)
    order = (by_key.agg(offset=("offset", "median"), order=("order", "min"), ms=("ms", "median"),
                        frames=("frame", "nunique"), share=("pixel_share", "median"), name=("name", "first"),
                        ran=("ran_ms", "median"))
             .sort_values(["offset", "order"], na_position="last", kind="stable"))
    order["queue"] = _queue_mode(keyed)
    spread = (keyed["ms"] - by_key["ms"].transform("median")).abs().groupby(keyed["key"]).median()
    keys = list(order.index)
    io = _io(keyed, keys)
    producers, sizes, notes = _producers(keys, io, pixels * DEFAULT_COLOR_BYTES)
    passes = []
    for key, name, queue, ms, frames, stated, spread_ms, ran in zip(
            keys, order["name"], order["queue"], order["ms"], order["frames"], order["share"],
            spread.reindex(order.index), order["ran"]):
        share = _share_of(str(name), float(stated), default_share, share_why, pixels,
                          bool(producers[key]), io[key][1])
        passes.append(CapturedPass(str(key), str(queue), float(ms), int(frames), share.value,
                                   tuple(producers[key]), int(sizes[key]), float(spread_ms), share,
                                   float(ran) if ran > ms + 5e-7 else None))
    return tuple(passes), notes


def _queue_mode(keyed: pd.DataFrame) -> pd.Series:
    """Each pass's most frequent queue (of a tie, the first in alphabetical order)."""
    counts = keyed.groupby(["key", "queue"], sort=False).size().reset_index(name="n")
    counts = counts.sort_values(["key", "n", "queue"], ascending=[True, False, True], kind="stable")
    return counts.drop_duplicates("key").set_index("key")["queue"]


def _share_of(name: str, stated: float, default: float | None, why: Mapping[str, str], pixels: int,
              reads_passes: bool, written: Mapping[str, int | None]) -> Share:
    """A pass's share: the capture's, else --pixel-share, else inferred from its name (the
    capture's, without the '#k' of a repeat), targets and reads."""
    if not math.isnan(stated):
        return Share(stated, STATED, why.get(name, ""))
    if default is not None:
        return Share(default, OPTION)
    value, reason = infer_share(name, pixels=pixels, reads_passes=reads_passes, written=written)
    return Share(value, INFERRED, reason)


def _io(keyed: pd.DataFrame, keys: list[str]) -> dict[str, tuple[tuple[str, ...], dict[str, int | None]]]:
    """Per pass: the resources it reads and those it writes with their bytes (None: unknown),
    from its first slice that names any (captures repeat them every frame)."""
    named = (keyed["reads"].map(len) > 0) | (keyed["writes"].map(len) > 0)
    first = pd.concat([keyed[named], keyed[~named]]).drop_duplicates("key")
    out: dict[str, tuple[tuple[str, ...], dict[str, int | None]]] = {}
    for key, reads, writes, sizes in zip(first["key"], first["reads"], first["writes"], first["bytes"]):
        out[str(key)] = (tuple(reads), dict(zip(writes, list(sizes) or [None] * len(writes))))
    for key in keys:
        out.setdefault(key, ((), {}))
    return out


def _producers(keys: list[str], io: dict[str, tuple[tuple[str, ...], dict[str, int | None]]],
               default_bytes: int) -> tuple[dict[str, list[str]], dict[str, int], list[str]]:
    """Reads resolved to the passes that wrote them (see the module doc), and each pass's
    output bytes: what it writes that some pass reads, plus the last pass's image."""
    reads: dict[str, list[str]] = {k: [] for k in keys}
    read_from: dict[str, set[str]] = {k: set() for k in keys}
    writers: dict[str, list[int]] = {}  # resource -> the positions of the passes writing it
    for j, key in enumerate(keys):
        for res in io[key][1]:
            writers.setdefault(res, []).append(j)
    for i, key in enumerate(keys):
        for res in io[key][0]:
            writer = _writer(writers.get(res), i, keys)
            if writer is None and res in reads:
                writer, res = res, "*"  # a pass's name: all it writes
            if writer is None:
                continue
            if writer not in reads[key]:
                reads[key].append(writer)
            read_from[writer].add(res)
    sizes, unknown = {}, []
    for key in keys:
        written = io[key][1]
        whole = key == keys[-1] or "*" in read_from[key]  # presented, or read by its name
        used = set(written) if whole else {r for r in read_from[key] if r in written}
        if whole and not written:
            used.add("")  # an output the capture does not name
        total = 0
        for res in used:
            size = written.get(res) if res else None
            if size is None:
                unknown.append(key)
                size = default_bytes
            total += size
        sizes[key] = total
    notes = []
    if unknown:
        shown = ", ".join(sorted(set(unknown))[:5]) + (" ..." if len(set(unknown)) > 5 else "")
        notes.append(f"output sizes not in the capture, taken as one colour target of the frame "
                     f"({default_bytes} bytes): {shown}")
    return reads, sizes, notes


def _writer(positions: list[int] | None, i: int, keys: list[str]) -> str | None:
    """The pass that wrote what the i-th pass reads: the last writer before it, else (the
    previous frame's) the last writer of the frame; None where no pass writes it."""
    if not positions:
        return None
    before = bisect.bisect_left(positions, i)
    return keys[positions[before - 1] if before else positions[-1]]


def _notes(slices: pd.DataFrame, keyed: pd.DataFrame, passes: tuple, frames: int,
           left_out: Mapping[str, float], views: int) -> list[str]:
    out = []
    transfer = slices[slices["queue"] == "transfer"]
    if len(transfer):
        out.append(f"transfer-queue work left out ({transfer['ms'].sum() / frames:.3f} ms per frame): "
                   "the schedules place their own copies")
    for where, ms in sorted(left_out.items()):
        out.append(f"not frame work, left out: {where} ({ms:.3f} ms in all)")
    partial = [p.name for p in passes[0] if p.frames < frames]
    if partial:
        out.append(f"passes missing from some frames (their median is over the frames they ran in): "
                   f"{', '.join(partial[:5])}{' ...' if len(partial) > 5 else ''}")
    out += _queue_notes(passes[0])
    return out


def _queue_notes(passes: tuple[CapturedPass, ...]) -> list[str]:
    """What the import made of compute-queue passes: run in order on the graphics queue, and
    those that overlapped graphics work cut to the time they added (:func:`exposed_times`)."""
    compute = [p.name for p in passes if p.queue == "compute"]
    if not compute:
        return []
    out = [f"ran on the compute queue in the capture: {', '.join(compute[:5])}"
           f"{' ...' if len(compute) > 5 else ''}; the schedules run every pass on the graphics "
           "queue, in order"]
    cut = [p for p in passes if p.ran_ms is not None]
    if cut:
        hidden = sum(cast(float, p.ran_ms) - p.gpu_ms for p in cut)
        shown = ", ".join(f"{p.name} {p.ran_ms:.3f} -> {p.gpu_ms:.3f} ms" for p in cut[:5])
        out.append(f"async compute: {len(cut)} compute pass(es) overlapped graphics work ({hidden:.3f} ms "
                   f"per frame hidden); each is written as the time it added to the frame ({shown}"
                   f"{' ...' if len(cut) > 5 else ''}), so one GPU runs the capture's frame time; "
                   "split across GPUs the overlap is assumed to survive (approximated: the model has "
                   "no queue per scene pass)")
    return out


# ----- async compute ---------------------------------------------------------------------------
def exposed_times(gpu: pd.DataFrame) -> pd.DataFrame:
    """The slices with each compute-queue slice's `ms` cut to the time it added to the GPU's
    busy time: the part of it when no graphics slice (of any frame: async work may run on into
    the next frame's), nor a compute slice that started before it, was running (whole ns);
    `ran_ms` keeps what it ran.

    Why: the schedules run a frame's passes one after the other on one queue (the scene has no
    queue per pass), so a pass that overlapped graphics work on an async-compute queue would add
    its whole time to the frame. Cut to what it added, the one-GPU frame takes the capture's
    busy time; split across GPUs, the pass keeps only that part of its cost (the overlap is
    assumed to survive the split), which the import notes. Without start times (a CSV) nothing
    is cut: a CSV's compute rows are taken as run in turn."""
    compute = (gpu["queue"] == "compute").to_numpy()
    out = gpu.assign(ran_ms=gpu["ms"])
    if not compute.any() or compute.all() or gpu["start_ns"].isna().any():
        return out
    starts, ends = out["start_ns"].to_numpy(), out["end_ns"].to_numpy()
    lo, hi = _union(starts[~compute], ends[~compute])
    below = _covered_below(lo, hi)
    rows = np.flatnonzero(compute)
    rows = rows[np.argsort(starts[rows], kind="stable")]  # in start order (ties: capture order)
    s, e = starts[rows], ends[rows]
    reach = np.maximum.accumulate(np.concatenate(([-np.inf], e[:-1])))  # latest end of those before
    c = np.clip(reach, s, e)  # [s, c): under an earlier compute slice
    hidden = np.round((c - s) + below(e) - below(c))
    ms = out["ms"].to_numpy(copy=True)
    ms[rows] = np.where(hidden > 0, np.maximum(0.0, ms[rows] - hidden / 1e6), ms[rows])
    out["ms"] = ms
    return out


def _union(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intervals as their union: sorted, disjoint (starts, ends)."""
    order = np.argsort(starts, kind="stable")
    s, e = starts[order], np.maximum.accumulate(ends[order])
    new = np.concatenate(([True], s[1:] > e[:-1]))  # starts after all before it ended
    first = np.flatnonzero(new)
    last = np.concatenate((first[1:] - 1, [len(s) - 1]))
    return s[first], e[last]


def _covered_below(lo: np.ndarray, hi: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """x -> how much of the disjoint sorted intervals [lo, hi) lies below x (vectorised)."""
    before = np.concatenate(([0.0], np.cumsum(hi - lo)))

    def below(x: np.ndarray) -> np.ndarray:
        i = np.searchsorted(lo, x, side="right") - 1  # the last interval starting at or before x
        at = np.maximum(i, 0)
        inside = np.clip(x - lo[at], 0.0, hi[at] - lo[at])
        return np.where(i >= 0, before[at] + inside, 0.0)
    return below


def _gpu_span(gpu: pd.DataFrame) -> float | None:
    if gpu["start_ns"].isna().any():
        return None
    per = gpu.groupby("frame").agg(lo=("start_ns", "min"), hi=("end_ns", "max"))
    return float(((per["hi"] - per["lo"]) / 1e6).median())


# ----- the experiment -------------------------------------------------------------------------
def experiment_text(frame: CapturedFrame, profile: Path, out: Path, frames: int = 60,
                    warmup: int = 10) -> str:
    """The experiment file of `frame` (TOML), naming `profile` relative to `out`'s folder."""
    ref = _profile_ref(profile, out)
    lines = [f"# Imported by `mgpusim frame import` from {_c(frame.source)}",
             f"# {frame.frames} {frame.frames_are}; every pass's gpu_ms is its median over them "
             f"({'one eye of two views' if frame.views == 2 else 'one view'}).",
             f"# The passes sum to {frame.gpu_ms:.3f} ms of GPU time per frame"
             + (f"; the GPU was busy {frame.gpu_span_ms:.3f} ms per frame." if frame.gpu_span_ms else "."),
             "# pixel_share: the part of a pass's time that scales with the pixels it draws (a",
             "# sort-first tile); the rest scales with the geometry it draws (a sort-last share).",
             "# Each pass's comment says where its share came from (the capture, --pixel-share, or",
             "# inferred from its name, targets and reads: docs/frame_captures.md); check the",
             "# inferred ones: `mgpusim advise` lists them and how its answer moves if they are off.",
             *(f"# note: {_c(n)}" for n in frame.notes),
             f"name = {_q(frame.name)}",
             f"description = {_q(f'frame imported from {frame.source}: {len(frame.passes)} passes')}",
             f"profile = {_q(ref)}", "", "[scene]", f"width = {frame.width}", f"height = {frame.height}"]
    for p in frame.passes:
        lines += ["", "[[scene.passes]]", f"name = {_q(p.name)}", 'kind = "captured"',
                  f"gpu_ms = {ms_text(p.gpu_ms)}" + (f"  # +- {p.spread_ms:.3g} ms over {p.frames} frame(s)"
                                               if p.frames > 1 else ""),
                  f"pixels = {frame.width * frame.height}",
                  f"pixel_share = {p.pixel_share:g}" + (f"  {_c(share_comment(p.share))}" if p.share else "")]
        if p.output_bytes:
            lines.append(f"output_bytes = {p.output_bytes}")
        if p.reads:
            lines.append("reads = [" + ", ".join(_q(r) for r in p.reads) + "]")
        if p.ran_ms is not None:
            lines.append(f"# ran {ms_text(p.ran_ms)} ms on the {p.queue} queue in the capture, overlapping "
                         f"graphics work; gpu_ms is the {ms_text(p.gpu_ms)} ms it added to the frame")
        elif p.queue != "graphics":
            lines.append(f"# ran on the {p.queue} queue in the capture")
    lines += ["", "[schedule]"] + schedule_lines(frame, frames, warmup)
    return "\n".join(lines) + "\n"


def _profile_ref(profile: Path, out: Path) -> str:
    """The profile as the experiment names it: relative to the experiment's folder where both
    lie under the working directory (a checkout moved elsewhere still works), else absolute."""
    here, prof, folder = Path.cwd().resolve(), profile.resolve(), out.resolve().parent
    if prof.is_relative_to(here) and folder.is_relative_to(here):
        return Path(os.path.relpath(prof, folder)).as_posix()
    return prof.as_posix()


def schedule_lines(frame: CapturedFrame, frames: int, warmup: int) -> list[str]:
    """One GPU: the frame as captured (a stereo frame's two views in turn on it, XR's simulated
    mode); `mgpusim advise` searches the multi-GPU schedules from there."""
    lines = ['name = "xr"', "gpus = 1", 'mode = "simulated"', "views = 2"] if frame.views == 2 else \
        ['name = "pipelining"', "gpus = 1"]
    lines += [f"frames = {frames}", f"warmup_frames = {warmup}"]
    if frame.views == 1 and any(p.reads for p in frame.passes):
        lines.append('consumer_waits = "reads"   # split across GPUs, a pass waits only for what it reads')
    if frame.cpu_ms:
        lines.append(f"cpu_frame_us = {frame.cpu_ms * 1000:.6g}   # the capture's CPU work per frame")
    return lines


def ms_text(ms: float) -> str:
    """A pass's time as the file writes it: six digits where they hold it to 0.05 ns, else to
    0.1 ns (a capture's times are whole ns; six digits alone would move a 13.944869 ms pass by
    131 ns, and the frame's sum with it)."""
    short = f"{ms:.6g}"
    return short if abs(float(short) - ms) <= 5e-8 else repr(round(ms, 7))


def _q(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's, and DEL, which JSON leaves, escaped)."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


#: What a TOML comment cannot hold (control characters but tab, and line breaks a reader may
#: take for the end of the comment), and lone surrogates, which UTF-8 cannot write.
_NOT_IN_COMMENT = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")


def _c(text: str) -> str:
    """Text for a comment: one line, each character a TOML comment cannot hold as \\uXXXX
    (a pass or track name or a path with a newline would otherwise end the comment)."""
    return _NOT_IN_COMMENT.sub(lambda m: f"\\u{ord(m.group()):04x}", text)


def check_experiment(text: str, out: Path) -> Experiment:
    """The written experiment as `simulate` will read it: an import that would not load is an
    error here, before any file is written."""
    import tomllib  # noqa: PLC0415
    return parse_experiment(tomllib.loads(text), str(out), base=out.resolve().parent)  # text, not a file
