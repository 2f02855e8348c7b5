"""The generated frames `advise`'s speed is measured on (benchmarks/advise_speed.py,
benchmarks/advise_passes.py, `mgpusim bench --advise`): a deferred renderer's 20 passes at
2560x1440 (shadow cascades, depth, G-buffer, decals, SSAO, lighting, volumetrics,
transparency, TAA reading last frame's output, post), with what each reads and writes; times
are typical of a current GPU at that size (an example, not a measurement). A frame of N passes
repeats it (each copy's passes renamed, reading its own targets), every pass's time divided by
the number of copies so that the frame stays about 11 ms. Kept here so that the benchmarks and
the bench command time the same frame."""
from __future__ import annotations

import math

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
HEADER = "pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n"


def frame20_csv() -> str:
    """The 20-pass frame as a capture table (`mgpusim frame import` reads it)."""
    return HEADER + "".join(f"{n},graphics,{ms},{r},{w},{b},{s}\n" for n, ms, r, w, b, s in PASSES)


def _tagged(names: str, copy: int) -> str:
    """A ;-separated list of resource names, each of copy `copy` of the frame."""
    return ";".join(f"{n}_{copy}" for n in names.split(";") if n)


def frame_csv(passes: int) -> str:
    """A capture table of `passes` passes: copies of the 20-pass frame, the last one cut short."""
    copies = math.ceil(passes / len(PASSES))
    rows = []
    for k in range(copies):
        for name, ms, reads, writes, size, share in PASSES:
            rows.append(f"{name}_{k},graphics,{ms / copies:.5f},{_tagged(reads, k)},{_tagged(writes, k)},"
                        f"{size},{share}\n")
    return HEADER + "".join(rows[:passes])
