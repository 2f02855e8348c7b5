"""Capture one frame of the runner's passes on lavapipe with RenderDoc (its in-app API).

What it draws: a frame of six passes made of the runner's own pass library
(mgpusim/real/passes/standalone.py), each inside a debug label naming it, as an engine labels
its passes: a shadow map and a G-buffer (meshes), lighting (a fragment loop), a particle
update (a compute dispatch), the particles drawn, and a post filter. RenderDoc's Vulkan layer
records the frame between StartFrameCapture and EndFrameCapture into an .rdc file; replaying
it (`mgpusim frame import`) times each action on the replaying GPU.

Run it from a checkout (RenderDoc 1.24 of Debian 12: `apt-get install renderdoccmd
python3-renderdoc`):

    ENABLE_VULKAN_RENDERDOC_CAPTURE=1 MGPUSIM_VK_VALIDATION=1 PYTHONPATH=$PWD \\
        .venv/bin/python tests/data/renderdoc/capture_lavapipe.py OUT.rdc

(`MGPUSIM_VK_VALIDATION=1` turns on VK_EXT_debug_utils, which the labels need, with the
validation layer.) The committed capture and the command that made it: PROVENANCE.md here.
"""
from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path
from typing import Any

from mgpusim.real.passes.particle_update import ParticleUpdate
from mgpusim.real.passes.standalone import FilterPass, FragmentLoop, Mesh, ParticleRender
from mgpusim.real.vulkan.device import Gpu
from mgpusim.real.vulkan.instance import Instance
from mgpusim.real.vulkan.vk_errors import vk

#: RenderDoc's in-app API 1.6.0 (renderdoc_app.h): the version asked for and the slots of the
#: functions used in its table of function pointers.
API_VERSION = 10600
SET_CAPTURE_PATH, GET_NUM_CAPTURES, GET_CAPTURE, START, END = 11, 13, 14, 19, 21
WIDTH, HEIGHT = 128, 96


def renderdoc_api() -> Any:
    """The API table of the RenderDoc library the Vulkan loader already loaded (as a layer)."""
    try:
        lib = ctypes.CDLL("librenderdoc.so", mode=os.RTLD_NOLOAD | os.RTLD_NOW)
    except OSError:
        sys.exit("RenderDoc's layer is not loaded: run with ENABLE_VULKAN_RENDERDOC_CAPTURE=1")
    table = ctypes.c_void_p()
    if not lib.RENDERDOC_GetAPI(API_VERSION, ctypes.byref(table)):
        sys.exit("RenderDoc refused in-app API 1.6.0")
    return ctypes.cast(table, ctypes.POINTER(ctypes.c_void_p * 27)).contents


def call(table: Any, slot: int, restype: Any, argtypes: tuple[Any, ...], *args: Any) -> Any:
    return ctypes.CFUNCTYPE(restype, *argtypes)(table[slot])(*args)


VOIDS = (ctypes.c_void_p, ctypes.c_void_p)


def labelled(gpu: Gpu, passes: list[tuple[str, Any]]) -> Any:
    """A recorder of the passes in order, each between vkCmdBegin/EndDebugUtilsLabelEXT."""
    v = vk()
    begin, end = (gpu.instance.proc(f"vkCmd{step}DebugUtilsLabelEXT") for step in ("Begin", "End"))
    labels = {name: v.VkDebugUtilsLabelEXT(pLabelName=name, color=[0.0, 0.0, 0.0, 1.0]) for name, _ in passes}

    def record(cmd: Any) -> None:
        for name, work in passes:
            begin(cmd, labels[name])
            work(cmd)
            end(cmd)
    return record


def main(out: Path) -> None:
    instance = Instance()
    with Gpu(instance, 0, owns_instance=True) as gpu:
        api = renderdoc_api()
        template = str(out.with_suffix("")).encode()
        call(api, SET_CAPTURE_PATH, None, (ctypes.c_char_p,), template)
        shadow = Mesh(gpu, 128, 128, 1_000)
        gbuffer = Mesh(gpu, WIDTH, HEIGHT, 3_000)
        lighting = FragmentLoop(gpu, WIDTH, HEIGHT, 400)
        update = ParticleUpdate(gpu, 1_024)
        particles = ParticleRender(gpu, WIDTH, HEIGHT, 1_024, vertices=update.vertices)
        post = FilterPass(gpu, WIDTH, HEIGHT, 60, 1)
        frame = labelled(gpu, [("Shadow map", shadow.record), ("GBuffer", gbuffer.record),
                               ("Lighting", lighting.record), ("Particle update", update.record),
                               ("Particles", particles.record), ("Post", post.record)])
        gpu.run("graphics", frame).wait()  # a frame before the captured one: pipelines warm
        call(api, START, None, VOIDS, None, None)
        gpu.run("graphics", frame).wait()
        if not call(api, END, ctypes.c_uint32, VOIDS, None, None):
            sys.exit("RenderDoc did not capture the frame")
        n = call(api, GET_NUM_CAPTURES, ctypes.c_uint32, ())
        path, size = ctypes.create_string_buffer(4096), ctypes.c_uint32(4096)
        call(api, GET_CAPTURE, ctypes.c_uint32, (ctypes.c_uint32, ctypes.c_char_p, ctypes.POINTER(ctypes.c_uint32),
                                                 ctypes.c_void_p), n - 1, path, ctypes.byref(size), None)
        written = Path(path.value.decode())
        written.replace(out)
        print(f"captured {out} ({out.stat().st_size} bytes)")
        for p in (post, particles, update, lighting, gbuffer, shadow):
            p.destroy()


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "frame.rdc").resolve())
