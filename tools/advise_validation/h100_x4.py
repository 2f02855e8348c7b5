"""Bring your own frame on 4x NVIDIA H100: capture, import, advise (up to 4 GPUs), run for real.

    PYTHONPATH=. python tools/advise_validation/h100_x4.py --out DIR [--deadline-s 240]

Five frames from the H100 studies' scenes, each captured on one GPU (devices 0-3, the
h100_x4 profile for all, h200_x4 on 4x H200): the five-step study's 4K fragment loop (sort-first's), the AFR
temporal scene (fragment loop + TAA filter at 1440p), the 2x H100 pipelining chain (four
passes at 1440p), the XR stereo mesh (Quest 3 eyes, both views on one GPU) and the five-step
4K mesh (sort-last's, 5M triangles: its 10M took ~7 s per run to build); the slow mesh last, so
that a deadline cuts it rather than the others. On these the options differ by
several times the run-to-run noise (unlike lavapipe's). The steps and the files written under
DIR: mgpusim/advise/on_hardware.py. The device-machine command is
tools/advise_validation/h100_x4.sh.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # tools/advise_validation/ -> the checkout
sys.path.insert(0, str(ROOT))

from mgpusim.advise.on_hardware import Setup, frames_of, main  # noqa: E402

X4, X2 = ROOT / "experiments" / "h100_x4", ROOT / "experiments" / "h100_x2"
ONE = {"schedule.gpus": 1}
SETUP = Setup(
    # the card's own profile: advise_validation.sh sets ADVISE_PROFILE=h200_x4 on H200s
    profile=ROOT / "hardware_profiles" / f"{os.environ.get('ADVISE_PROFILE', 'h100_x4')}.toml",
    frames=frames_of((
        ("fragment loop", X4 / "sort_first.toml", ONE),
        ("temporal AA", X4 / "afr_temporal.toml", ONE),
        ("pipelining chain", X2 / "pipelining.toml", ONE),
        ("stereo mesh", X4 / "xr.toml", {**ONE, "schedule.mode": "simulated", "schedule.views": 2}),
        ("mesh", X4 / "sort_last.toml", {**ONE, "scene.passes.0.triangles": 5_000_000}),
    )),
    # workers=1: the search runs in this process (a pool would fork a process holding the
    # driver's VkInstance; on ~50 options the serial search takes seconds)
    max_gpus=4, repeats=2, devices=(0, 1, 2, 3), frames_per_run=40, workers=1)

if __name__ == "__main__":
    sys.exit(main(SETUP, __doc__.splitlines()[0]))
