"""The whole bring-your-own-frame path on lavapipe: capture, import, advise, run for real.

    PYTHONPATH=. python tools/advise_validation/lavapipe.py --out DIR [--repeats 3]

Five frames (the lavapipe study's scenes: the pipelining chain, a fragment loop, a mesh, a
fragment loop with temporal AA, a stereo mesh), advised up to 3 GPUs on the lavapipe profile;
the steps and the files written under DIR: mgpusim/advise/on_hardware.py. About 4
minutes on the 2-core development machine.
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # tools/advise_validation/ -> the checkout
sys.path.insert(0, str(ROOT))

from mgpusim.advise.on_hardware import Setup, frames_of, main  # noqa: E402

HERE = ROOT / "experiments" / "lavapipe"
SETUP = Setup(
    profile=ROOT / "hardware_profiles" / "lavapipe_2core.toml",
    frames=frames_of((
        ("pipelining chain", HERE / "pipelining.toml", {"schedule.gpus": 1}),
        ("fragment loop", HERE / "sort_first.toml", {"schedule.gpus": 1}),
        ("mesh", HERE / "sort_last.toml", {"schedule.gpus": 1}),
        ("temporal AA", HERE / "afr_temporal.toml", {"schedule.gpus": 1}),
        ("stereo mesh", HERE / "xr.toml", {"schedule.gpus": 1, "schedule.mode": "simulated",
                                           "schedule.views": 2}),
    )),
    max_gpus=3, repeats=3, workers=2)

if __name__ == "__main__":
    sys.exit(main(SETUP, __doc__.splitlines()[0]))
