"""How long `mgpusim advise` takes on a 20-pass frame searched over every option (target:
under 60 s on 2 cores).

    PYTHONPATH=. python benchmarks/advise_speed.py [--workers 2] [--out DIR]

The frame: a deferred renderer's 20 passes at 2560x1440 (shadow cascades, depth, G-buffer,
decals, SSAO, lighting, volumetrics, transparency, TAA reading last frame's output, post),
with what each reads and writes, imported from CSV as a user would; times are typical of a
current GPU at that size (an example, not a measurement). The whole command runs: the search
at the analytic level, the confirmation at full fidelity and the report with three timelines.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.cli import main as cli  # noqa: E402

RT = 2560 * 1440 * 4  # an RGBA8 target at 2560x1440
PASSES = [  # name, gpu_ms, reads, writes, bytes, pixel_share
    ("shadow0", 0.45, "", "sm0", 4194304, 0.0), ("shadow1", 0.40, "", "sm1", 4194304, 0.0),
    ("shadow2", 0.35, "", "sm2", 4194304, 0.0), ("shadow3", 0.30, "", "sm3", 4194304, 0.0),
    ("depth", 0.60, "", "depth", RT, 0.3), ("gbuffer", 1.80, "depth", "gb0;gb1;gb2", f"{RT};{RT};{RT}", 0.6),
    ("decals", 0.25, "depth;gb0", "gb0", RT, 1.0), ("hiz", 0.10, "depth", "hiz", RT // 3, 1.0),
    ("ssao", 0.55, "depth;gb1;hiz", "ao", RT // 4, 1.0), ("ssao_blur", 0.20, "ao", "ao", RT // 4, 1.0),
    ("lighting", 1.60, "gb0;gb1;gb2;ao;sm0;sm1;sm2;sm3", "hdr", 2 * RT, 1.0),
    ("volumetric", 0.70, "depth;sm0", "fog", RT // 4, 1.0), ("sky", 0.15, "depth", "hdr", 2 * RT, 1.0),
    ("transparent", 0.90, "depth;hdr;fog", "hdr", 2 * RT, 0.4),
    ("taa", 0.35, "hdr;taa_out;depth", "taa_out", 2 * RT, 1.0),
    ("bloom_down", 0.30, "taa_out", "bloom", RT // 2, 1.0), ("bloom_up", 0.25, "bloom", "bloom", RT // 2, 1.0),
    ("tonemap", 0.20, "taa_out;bloom", "ldr", RT, 1.0), ("fxaa", 0.18, "ldr", "aa", RT, 1.0),
    ("ui", 0.12, "aa", "backbuffer", RT, 1.0),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / "advice"
        csv = Path(tmp) / "frame20.csv"
        csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n" + "".join(
            f"{n},graphics,{ms},{r},{w},{b},{s}\n" for n, ms, r, w, b, s in PASSES))
        exp = Path(tmp) / "frame20.toml"
        cli(["frame", "import", str(csv), "--size", "2560x1440", "--out", str(exp),
             "--profile", str(ROOT / "hardware_profiles" / "pcie4_pair.toml")])
        start = time.perf_counter()
        code = cli(["advise", str(exp), "--out", str(out), "--workers", str(args.workers)])
        took = time.perf_counter() - start
    print(f"advise on a {len(PASSES)}-pass frame: {took:.1f} s with {args.workers} worker(s) "
          f"on {os.cpu_count()} CPU(s), report included (target: under 60 s on 2 cores)")
    sys.exit(code)


if __name__ == "__main__":
    main()
