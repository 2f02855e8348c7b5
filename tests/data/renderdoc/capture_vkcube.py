"""Capture frame 100 of vkcube (vulkan-tools) on lavapipe with RenderDoc's Python module.

RenderDoc launches vkcube with its capture layer injected (ExecuteAndInject), connects to it
(target control) and asks for frame 100; vkcube presents to an X display, so run it under a
virtual one (as root, or with write access to the output folder):

    xvfb-run -a python3 tests/data/renderdoc/capture_vkcube.py tests/data/renderdoc/vkcube

which writes tests/data/renderdoc/vkcube_frame100.rdc (python3: the one python3-renderdoc was
built for, Debian 12's 3.11). vkcube stops with an assertion after its 200 frames under Xvfb
(its swapchain is lost); the capture is written before that.
"""
from __future__ import annotations

import sys
import time

sys.path.insert(0, "/usr/lib/python3/dist-packages")  # Debian's python3-renderdoc
import renderdoc as rd  # type: ignore[import-not-found]  # noqa: E402

FRAME = 100


def main(template: str) -> None:
    launched = rd.ExecuteAndInject("/usr/bin/vkcube", "/tmp", "--c 200", [], template,
                                   rd.GetDefaultCaptureOptions(), False)
    target = rd.CreateTargetControl("", launched.ident, "mgpusim", True)
    target.QueueCapture(FRAME, 1)
    started = time.time()
    while time.time() - started < 60:
        msg = target.ReceiveMessage(None)
        if msg.type == rd.TargetControlMessageType.NewCapture:
            print(f"captured {msg.newCapture.path} (frame {msg.newCapture.frameNumber})")
            break
        if msg.type == rd.TargetControlMessageType.Disconnected:
            sys.exit("vkcube ended before its frame was captured")
    target.Shutdown()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "vkcube")
