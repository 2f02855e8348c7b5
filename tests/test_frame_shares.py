"""Pixel shares at import: inferred from what the capture holds (the pass's name, the targets
it writes, what it reads) where the capture and --pixel-share do not say, each with its reason
in the experiment file, and read back from there."""
from __future__ import annotations

from pathlib import Path

import pytest

from mgpusim import load_experiment, simulate
from mgpusim.cli import main
from mgpusim.frames.shares import INFERRED, OPTION, STATED, frame_sized, infer_share, recorded_shares, words

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "hardware_profiles" / "pcie4_pair.toml"
RUN = ROOT / "data/lavapipe/history/main_job_2026-11-25/runs/pipe_1gpu/steady"
W, H = 1920, 1080
RT = W * H * 4
#: A deferred frame with 32 MB shadow cascades and a depth pre-pass, no pixel shares given.
DEFERRED = ("pass,queue,gpu_ms,reads,writes,bytes\n"
            f"shadow_cascades,graphics,1.2,,csm,{32 << 20}\n"
            f"depth_prepass,graphics,0.5,,depth,{RT}\n"
            f"gbuffer,graphics,2.0,depth,gb0;gb1,{RT};{RT}\n"
            f"ssao,compute,0.6,depth;gb1,ao,{RT // 4}\n"
            f"lighting,graphics,1.8,gb0;gb1;ao;csm,hdr,{2 * RT}\n"
            f"xyz,graphics,0.3,hdr,out,{RT}\n"
            f"bake_noise,graphics,0.1,,noise,{32 * 32 * 32 * 4}\n")


def _import(tmp: Path, text: str, *extra: str) -> Path:
    csv = tmp / "deferred.csv"
    csv.write_text(text)
    assert main(["frame", "import", str(csv), "--size", f"{W}x{H}", "--profile", str(PROFILE),
                 "--out", str(tmp), *extra]) == 0
    return tmp / "deferred.toml"


def _shares(path: Path):
    exp = load_experiment(path)
    return recorded_shares(path, {p.name: p.param("pixel_share") for p in exp.scene.passes})


# ----- the rules ------------------------------------------------------------------------------
@pytest.mark.parametrize("name,share", [
    ("shadow_cascades", 0.0), ("ShadowMap2", 0.0), ("csm", 0.0), ("sm3", 0.0), ("light_culling", 0.0),
    ("depth_prepass", 0.25), ("ZPrepass", 0.25), ("depth", 0.25),
    ("gbuffer", 0.5), ("GBuffer", 0.5), ("g_buffer", 0.5), ("transparent", 0.5), ("opaque_forward", 0.5),
    ("ssao", 1.0), ("ssao_blur", 1.0), ("lighting", 1.0), ("taa", 1.0), ("tonemap", 1.0), ("post_ui", 1.0),
    ("bloom_down", 1.0), ("hiz", 1.0), ("depth_of_field", 1.0), ("shadow_mask", 1.0), ("sky", 1.0),
])
def test_names_by_the_engines_conventions(name, share):
    got, why = infer_share(name, pixels=W * H, reads_passes=False, written={})
    assert got == share and why.startswith(f"the name {name!r}")


def test_targets_and_reads_where_the_name_says_nothing():
    px = W * H
    assert words("myPass_2") == "my pass 2"
    assert infer_share("xyz", pixels=px, reads_passes=False, written={"a": 32 << 20})[0] == 0.0  # not frame-sized
    assert infer_share("xyz", pixels=px, reads_passes=True, written={"a": RT})[0] == 1.0  # full-screen
    assert infer_share("xyz", pixels=px, reads_passes=True, written={"a": RT // 4})[0] == 1.0  # half resolution
    assert infer_share("xyz", pixels=px, reads_passes=False, written={"a": RT})[0] == 0.5  # draws the scene
    share, why = infer_share("xyz", pixels=px, reads_passes=True, written={"a": None})
    assert share == 0.5 and "nothing" in why
    assert frame_sized(RT, px) and frame_sized(px // 4, px) and not frame_sized(32 << 20, px)


# ----- the import -----------------------------------------------------------------------------
def test_the_import_infers_each_share_and_says_how(tmp_path, capsys):
    out = _import(tmp_path, DEFERRED)
    printed = capsys.readouterr().out
    assert "pixel_share inferred for 7 of 7 pass(es)" in printed
    shares = _shares(out)
    assert {n: s.value for n, s in shares.items()} == {
        "shadow_cascades": 0.0, "depth_prepass": 0.25, "gbuffer": 0.5, "ssao": 1.0, "lighting": 1.0,
        "xyz": 1.0, "bake_noise": 0.0}
    assert all(s.source == INFERRED for s in shares.values())
    assert "shadow map" in shares["shadow_cascades"].why
    assert "full-screen" in shares["xyz"].why  # by what it reads and writes
    assert "131072 bytes" in shares["bake_noise"].why  # by the size of its target
    text = out.read_text()
    assert "pixel_share = 0  # inferred: the name 'shadow_cascades'" in text


def test_the_capture_and_the_option_win_over_inference(tmp_path):
    out = _import(tmp_path, "pass,queue,gpu_ms,writes,bytes,pixel_share\n"
                            f"shadow_cascades,graphics,1.2,csm,{32 << 20},0.1\n"
                            f"gbuffer,graphics,2.0,gb0,{RT},\n", "--pixel-share", "0.8")
    shares = _shares(out)
    assert (shares["shadow_cascades"].value, shares["shadow_cascades"].source) == (0.1, STATED)
    assert (shares["gbuffer"].value, shares["gbuffer"].source) == (0.8, OPTION)
    assert not shares["shadow_cascades"].assumed and shares["gbuffer"].assumed


def test_a_measured_run_states_its_shares_by_pass_kind(tmp_path):
    out = tmp_path / "run.toml"
    assert main(["frame", "import", str(RUN), "--profile", str(PROFILE), "--out", str(out)]) == 0
    shares = _shares(out)
    assert all(s.source == STATED and "pass kind" in s.why for s in shares.values())


def test_an_experiment_without_the_import_record_says_so(tmp_path):
    got = recorded_shares(tmp_path / "missing.toml", {"a": 0.3})
    assert got["a"].value == 0.3 and got["a"].source == "set in the experiment" and got["a"].assumed


def test_inferred_shares_keep_sort_first_from_scaling_as_if_every_pass_were_pixels(tmp_path):
    """The silent assumption of old: every share 1, and sort-first on 4 GPUs scales ~4x even
    with the shadow cascades and pre-pass every GPU must draw whole."""
    four = {"schedule": {"name": "sort_first", "gpus": 4, "balance": True}, "profile.gpu_count": 4}
    deferred = _import(tmp_path, DEFERRED)
    (tmp_path / "ones").mkdir()
    inferred = simulate(load_experiment(deferred, four), record_trace=False).summary["frame_time_ms"]
    ones = _import(tmp_path / "ones", DEFERRED, "--pixel-share", "1")
    naive = simulate(load_experiment(ones, four), record_trace=False).summary["frame_time_ms"]
    one = simulate(load_experiment(deferred), record_trace=False).summary["frame_time_ms"]
    assert one / naive > 3.5 and one / inferred < 2.5
