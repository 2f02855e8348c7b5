"""Replaying a RenderDoc capture to time its actions: the part that runs RenderDoc.

A RenderDoc capture (`.rdc`) holds a frame's API calls and the resources they use, no times:
RenderDoc measures GPU time by replaying the frame and timing each action (draw, dispatch,
copy, clear) alone with the `GPU Duration` counter (timestamp queries on the replaying GPU;
https://renderdoc.org/docs/python_api/replay_analysis.html, "Fetching counters"). This module
is run as a child process (`python -m mgpusim.frames.rdc_replay CAPTURE REPLAYS`) by
:mod:`mgpusim.frames.rdc`, so that RenderDoc's library, its global state and a crash on a
damaged file stay out of the importing process. It prints one JSON object: the actions in
event order with their debug-marker path, render pass, targets, what they read and write, and
their GPU durations (seconds, one list per replay); the resources' sizes; what replayed it.
On a failure it prints `{"error": ...}` and exits 3.

RenderDoc's Python module (`renderdoc.so`) is found in the folders of `RENDERDOC_PYTHON_PATH`
where that is set, else as `import renderdoc`, else where Debian's python3-renderdoc puts it.
It is built for one Python version (Debian 12's: 3.11).
"""
from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

#: Where RenderDoc's Python module is looked for after `import renderdoc` (Debian/Ubuntu's
#: python3-renderdoc package).
MODULE_FOLDERS = ("/usr/lib/python3/dist-packages",)
#: Exit status of a replay that failed with a message (printed as {"error": ...}).
FAILED = 3


def module_folders() -> list[str]:
    """Where `renderdoc.so` is looked for: the folders of RENDERDOC_PYTHON_PATH where it is
    set (RenderDoc's own build: its lib folder), else :data:`MODULE_FOLDERS`."""
    given = os.environ.get("RENDERDOC_PYTHON_PATH")
    return [f for f in given.split(os.pathsep) if f] if given is not None else list(MODULE_FOLDERS)


def module_path() -> Path | None:
    """RenderDoc's Python module found on disk (None: not found). Checked without loading it."""
    return next((Path(f) / "renderdoc.so" for f in module_folders() if (Path(f) / "renderdoc.so").is_file()), None)


def load_renderdoc() -> Any:
    """RenderDoc's Python module: from RENDERDOC_PYTHON_PATH where that is set, else `import
    renderdoc` where this Python has it, else :data:`MODULE_FOLDERS`; ImportError naming where
    it was looked for."""
    if "RENDERDOC_PYTHON_PATH" not in os.environ:
        try:
            import renderdoc  # type: ignore[import-not-found]  # noqa: PLC0415
            return renderdoc
        except ImportError:
            pass
    path = module_path()
    if path is None:
        raise ImportError(f"RenderDoc's Python module (renderdoc.so) is not in this Python's path, nor in "
                          f"{os.pathsep.join(module_folders()) or 'RENDERDOC_PYTHON_PATH (empty)'}")
    loader = importlib.machinery.ExtensionFileLoader("renderdoc", str(path))
    spec = importlib.util.spec_from_file_location("renderdoc", path, loader=loader)
    assert spec is not None  # a file location with a loader always gives a spec
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    sys.modules["renderdoc"] = module
    return module


def _rid(value: Any) -> int:
    """A ResourceId as its number (0: none)."""
    m = re.search(r"(\d+)$", str(value))
    return int(m.group(1)) if m else 0


def replay(path: str, replays: int) -> dict[str, Any]:
    """The capture's actions and their GPU durations over `replays` replays (see the module doc)."""
    rd = load_renderdoc()
    rd.InitialiseReplay(rd.GlobalEnvironment(), [])
    cap = rd.OpenCaptureFile()
    try:
        status = cap.OpenFile(path, "", None)
        if not status.OK():
            raise RuntimeError(f"RenderDoc cannot open it as a capture: {status.Message()}")
        if cap.LocalReplaySupport() != rd.ReplaySupport.Supported:
            raise RuntimeError(f"RenderDoc cannot replay this {cap.DriverName()} capture on this machine")
        status, ctl = cap.OpenCapture(rd.ReplayOptions(), None)
        if not status.OK():
            raise RuntimeError(f"RenderDoc cannot replay it: {status.Message()}")
        try:
            return _record(rd, cap, ctl, replays)
        finally:
            ctl.Shutdown()
    finally:
        cap.Shutdown()
        rd.ShutdownReplay()


def _record(rd: Any, cap: Any, ctl: Any, replays: int) -> dict[str, Any]:
    actions = _actions(rd, ctl)
    timed = {a["event"] for a in actions}
    durations: dict[int, list[float]] = {e: [] for e in timed}
    for _ in range(replays):
        got = {r.eventId: r.value.d for r in ctl.FetchCounters([rd.GPUCounter.EventGPUDuration])}
        for e in timed:
            durations[e].append(float(got.get(e, 0.0)))
    for a in actions:
        a["seconds"] = durations[a["event"]]
    frame = int(ctl.GetFrameInfo().frameNumber)
    gpus = [f"{g.name} ({g.driver})" if g.driver else g.name for g in cap.GetAvailableGPUs()]
    return {"tool": f"RenderDoc {rd.GetVersionString()}", "api": cap.DriverName(),
            "machine": cap.RecordedMachineIdent().strip(), "frame": None if frame >= 2 ** 32 - 1 else frame,
            "replays": replays, "replay_gpu": gpus[0] if gpus else "",
            "actions": actions,
            "resources": _resources(rd, ctl)}


def _actions(rd: Any, ctl: Any) -> list[dict[str, Any]]:
    """Every action that does GPU work, in event order, with its marker path and render pass."""
    sf = ctl.GetStructuredFile()
    flags = rd.ActionFlags
    kinds = (("draw", flags.Drawcall), ("dispatch", flags.Dispatch), ("copy", flags.Copy),
             ("clear", flags.Clear), ("resolve", flags.Resolve))
    out: list[dict[str, Any]] = []
    state = {"pass": -1, "inside": False}

    def walk(items: Any, markers: list[str]) -> None:
        for a in items:
            if a.flags & flags.BeginPass:
                state["pass"] += 1
                state["inside"] = True
            kind = next((k for k, f in kinds if a.flags & f), None)
            if a.flags & flags.PushMarker:
                walk(a.children, [*markers, a.GetName(sf)])
            elif kind is not None:
                out.append({"event": int(a.eventId), "name": a.GetName(sf), "kind": kind,
                            "markers": markers, "render_pass": state["pass"] if state["inside"] else -1,
                            **_bindings(rd, ctl, a, kind)})
            elif len(a.children):
                walk(a.children, markers)
            if a.flags & flags.EndPass:
                state["inside"] = False

    walk(ctl.GetRootActions(), [])
    return out


def _bindings(rd: Any, ctl: Any, action: Any, kind: str) -> dict[str, list[int]]:
    """What an action writes (colour and depth targets, storage it may write, a copy's
    destination) and reads (textures and buffers its shaders read, vertex and index buffers,
    a copy's source)."""
    if kind in ("copy", "resolve", "clear"):
        return {"writes": [r for r in (_rid(action.copyDestination),) if r],
                "reads": [r for r in (_rid(action.copySource),) if r]}
    ctl.SetFrameEvent(action.eventId, True)
    ps = ctl.GetPipelineState()
    stages = [rd.ShaderStage.Compute] if kind == "dispatch" else \
        [rd.ShaderStage.Vertex, rd.ShaderStage.Hull, rd.ShaderStage.Domain, rd.ShaderStage.Geometry,
         rd.ShaderStage.Fragment]
    reads: list[int] = []
    writes = [_rid(o) for o in action.outputs] + [_rid(action.depthOut)]
    for stage in stages:
        for bound in ps.GetReadOnlyResources(stage):
            reads += [_rid(r.resourceId) for r in bound.resources]
        for bound in ps.GetReadWriteResources(stage):
            writes += [_rid(r.resourceId) for r in bound.resources]
    if kind == "draw":  # the vertex buffers its pipeline reads (others stay bound from earlier draws)
        used = {attr.vertexBuffer for attr in ps.GetVertexInputs() if attr.used}
        reads += [_rid(b.resourceId) for i, b in enumerate(ps.GetVBuffers()) if i in used]
        if action.flags & rd.ActionFlags.Indexed:
            reads.append(_rid(ps.GetIBuffer().resourceId))
    return {"writes": list(dict.fromkeys(w for w in writes if w)),  # colour targets first, then depth, storage
            "reads": list(dict.fromkeys(r for r in reads if r))}


def _resources(rd: Any, ctl: Any) -> dict[str, dict[str, Any]]:
    """Textures and buffers by id: name, bytes, and a texture's size and whether it is a
    swapchain image (what the frame presents)."""
    names = {_rid(r.resourceId): r.name for r in ctl.GetResources()}
    out: dict[str, dict[str, Any]] = {}
    for t in ctl.GetTextures():
        rid = _rid(t.resourceId)
        out[str(rid)] = {"name": names.get(rid, f"texture {rid}"), "bytes": int(t.byteSize),
                         "width": int(t.width), "height": int(t.height),
                         "swapchain": bool(t.creationFlags & rd.TextureCategory.SwapBuffer)}
    for b in ctl.GetBuffers():
        rid = _rid(b.resourceId)
        out[str(rid)] = {"name": names.get(rid, f"buffer {rid}"), "bytes": int(b.length)}
    return out


def main(argv: list[str]) -> int:
    try:
        record = replay(argv[0], int(argv[1]))
    except (ImportError, RuntimeError) as exc:
        print(json.dumps({"error": str(exc)}))
        return FAILED
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
