"""How much of a captured pass's time scales with the pixels it draws (`pixel_share`), where the
capture does not say: inferred from what the capture holds, with the reason.

A pass's `pixel_share` splits its time: that share scales with the pixels a schedule gives it
(a sort-first tile), the rest with its geometry (a sort-last share). A capture rarely states it,
and it decides how far sort-first scales: a shadow pass at 1 would split across tiles though
every GPU must draw the whole shadow map. :func:`infer_share` reads, in this order:

1. the pass's **name**, by the conventions engines name passes with (:data:`NAME_RULES`: shadow
   maps and culling 0, a depth pre-pass 0.25, G-buffer and forward passes 0.5, screen-space
   passes such as SSAO, lighting, TAA and post-processing 1);
2. the **targets it writes**: a target whose size is no whole number of quarter bytes per pixel
   of the frame is not the frame's (a shadow cascade, a look-up table): drawn whole on every
   GPU, 0;
3. **what it reads**: a pass that reads other passes' outputs and writes frame-sized targets is
   a full-screen pass, 1; one that reads none draws the scene into the frame, 0.5;
4. nothing of the above: 0.5.

The import writes each pass's share with how it was found as a comment on its `pixel_share`
line (:func:`share_comment`); :func:`recorded_shares` reads them back for `mgpusim advise`,
which lists them and how the answer moves if they are off.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

#: Where a pass's share came from, as the experiment file's comment says it.
STATED, OPTION, INFERRED = "stated in the capture", "--pixel-share", "inferred"


@dataclass(frozen=True)
class Share:
    """A pass's pixel share and where it came from (`source`: one of STATED, OPTION,
    INFERRED, or 'set in the experiment' where no import recorded it) and why."""

    value: float
    source: str
    why: str = ""

    @property
    def assumed(self) -> bool:
        """Whether the capture did not state it (so that the answer's sensitivity covers it)."""
        return self.source != STATED

    @property
    def words(self) -> str:
        return f"{self.source}: {self.why}" if self.why else self.source


#: Name conventions: (pattern over the pass's words, share, why), the first that matches wins.
#: Words: the name in lower case, split at non-letters and at lower-to-upper case changes.
NAME_RULES: tuple[tuple[str, float, str], ...] = (
    (r"depth of field|dof|bokeh|hi ?z|depth (?:pyramid|downsample|resolve|copy)|"
     r"(?:down|up)sample|mips?|shadows? (?:mask|resolve|filter|denoise)|screen space shadows?|"
     r"contact shadows?",
     1.0, "a full-screen pass over the frame's pixels (depth of field, a depth pyramid, a resample, "
          "a screen-space shadow mask)"),
    (r"shadows?|csm|cascades?|shadowmap|sm\d",
     0.0, "a shadow map: every GPU draws the whole map, so its time goes with the geometry"),
    (r"cull|culling|skin|skinning|bvh|blas|tlas|simulat|particle (?:update|sim)",
     0.0, "geometry or simulation work, independent of the frame's pixels"),
    (r"pre ?pass|prepass|z ?pre|zprepass|early z|z ?only|depth",
     0.25, "a depth pre-pass: mostly vertex work, which every tile repeats"),
    (r"g ?buffer|gbuf|gbuffer|base ?pass|opaque|forward|geometry|scene|mesh|terrain|foliage|"
     r"transparen\w*|translucen\w*|particles?|alpha|water|glass",
     0.5, "draws the scene's geometry into the frame: its vertex work repeats on every tile, "
          "its shading splits; taken as half and half"),
    (r"ssao|hbao|gtao|ao|ssr|ssgi|reflections?|light\w*|shad(?:e|ing)|deferred|resolve|"
     r"composite|combine|tone ?map\w*|bloom|blur|taa|fxaa|smaa|msaa|aa|post\w*|fog|volumetric\w*|"
     r"sky|atmosphere|upscal\w*|fsr|dlss|sharpen\w*|grad(?:e|ing)|lut|vignette|motion blur|"
     r"ui|hud|overlay|blit|copy|decals?|present",
     1.0, "a screen-space pass: its time goes with the pixels it shades"),
)
#: With nothing to go on.
UNKNOWN = (0.5, "nothing in the capture tells: taken as half pixels, half geometry")


def words(name: str) -> str:
    """A pass's name as lower-case words: `ShadowCascade_2` -> `shadow cascade 2`."""
    spaced = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", " ", name)
    return " ".join(re.split(r"[^a-z0-9]+", spaced.lower())).strip()


def infer_share(name: str, *, pixels: int, reads_passes: bool, written: Mapping[str, int | None]
                ) -> tuple[float, str]:
    """(pixel share, why) of a pass the capture gives no share for (see the module doc).
    `reads_passes`: it reads another pass's output; `written`: its targets and their bytes
    (None: unknown)."""
    text = f" {words(name)} "
    for pattern, share, why in NAME_RULES:
        if re.search(rf"(?<![a-z0-9])(?:{pattern})(?![a-z0-9])", text):
            return share, f"the name {name!r}: {why}"
    sizes = [b for b in written.values() if b]
    off = [b for b in sizes if not frame_sized(b, pixels)]
    if off:
        return 0.0, (f"writes a target of {off[0]} bytes, no whole number of quarter bytes per pixel "
                     f"of the frame's {pixels}: not the frame's (a shadow map, a table), drawn whole "
                     "on every GPU")
    if sizes and reads_passes:
        return 1.0, "reads other passes' outputs and writes frame-sized targets: a full-screen pass"
    if sizes:
        return 0.5, ("reads no pass's output and writes frame-sized targets: draws the scene into the "
                     "frame, taken as half pixels, half geometry")
    return UNKNOWN[0], UNKNOWN[1]


def frame_sized(nbytes: int, pixels: int) -> bool:
    """Whether a target of `nbytes` can be the frame's, at full or half resolution: a whole
    number of quarter bytes per pixel, up to 64 bytes per pixel."""
    quarters = 4 * nbytes / pixels
    return abs(quarters - round(quarters)) < 1e-9 and 1 <= round(quarters) <= 256


def share_comment(share: Share) -> str:
    """The comment the import writes after a pass's `pixel_share` (one line, no newline)."""
    return f"# {share.words}".replace("\n", " ")


_BLOCK = re.compile(r"^\s*\[\[\s*scene\.passes\s*\]\]\s*$")
_NAME = re.compile(r"^\s*name\s*=\s*(\"(?:[^\"\\]|\\.)*\")\s*(?:#.*)?$")
_SHARE = re.compile(r"^\s*pixel_share\s*=\s*([0-9.eE+-]+)\s*(?:#\s*(?P<note>.*))?$")


def recorded_shares(path: str | Path, shares: Mapping[str, float]) -> dict[str, Share]:
    """Each captured pass's share (`shares`: name -> the scene's value) with where it came from,
    as the import's comment in the experiment file at `path` records it, else 'set in the
    experiment'. A file that cannot be read records nothing."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    notes: dict[str, str] = {}
    current: str | None = None
    for line in lines:
        if _BLOCK.match(line):
            current = None
            continue
        if current is None and (m := _NAME.match(line)):
            current = json.loads(m.group(1))  # text, not a file: a quoted name in a comment
            continue
        if current is not None and (m := _SHARE.match(line)):
            notes[current] = (m.group("note") or "").strip()
    return {name: _parse(value, notes.get(name, "")) for name, value in shares.items()}


def _parse(value: float, note: str) -> Share:
    for source in (STATED, OPTION, INFERRED):
        if note == source or note.startswith(source + ":"):
            return Share(value, source, note[len(source) + 1:].strip())
    return Share(value, "set in the experiment")
