"""The texture term of a mesh and per-section memory: exact timeline, memory per GPU, bad input."""
from __future__ import annotations

import copy

import pytest

from mgpusim import InputError, simulate
from mgpusim.model.profile import parse_profile
from mgpusim.schedules.experiment import parse_experiment
from mgpusim.schedules.memory_check import check_memory, memory_report
from mgpusim.schedules.program import build_program
from tests.conftest import profile_dict

SECTIONS = [{"name": "a", "geometry_bytes": 1000, "texture_bytes": 3000},
            {"name": "b", "geometry_bytes": 2000, "texture_bytes": 2000},
            {"name": "c", "geometry_bytes": 500, "texture_bytes": 500}]


def make(scene_extra=None, memory=8 << 30, texture_coef=0.5, schedule="sort_last", **sched):
    prof = profile_dict(gpus=2)
    prof["gpus"][0]["memory_bytes"] = memory
    if texture_coef is not None:
        prof["gpus"][0]["costs"]["mesh"]["ns_per_texture_byte"] = texture_coef
    mesh = {"name": "p", "kind": "mesh", "triangles": 800}
    scene = {"width": 8, "height": 4, "passes": [mesh], **copy.deepcopy(scene_extra or {})}
    data = {"name": "t", "scene": scene,
            "schedule": {"name": schedule, "gpus": 2, "frames": 3, "warmup_frames": 1, **sched}}
    return parse_experiment(data, "t.toml", profile=parse_profile(prof, "p.toml"))


def test_mesh_texture_term_exact_timeline():
    """Sort-last on 2 GPUs: each draws half of 800 triangles (400 ns) and samples half of the
    400 decoded texture bytes at 0.5 ns each (100 ns): renders 0-500. GPU 1's 192 B cross at
    1 B/ns: d2h 500-692, host copy -884, h2d -1076; composite 32 px -1108; present 1118."""
    exp = make({"passes": [{"name": "p", "kind": "mesh", "triangles": 800, "texture_bytes": 400}]})
    r = simulate(exp)
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert (f0.loc["render0", "end_ns"], f0.loc["render1", "end_ns"]) == (500, 500)
    assert f0.loc["present", "end_ns"] == 1118
    render = next(t for t in build_program(exp).templates[0] if t.name == "render1")
    assert render.work["texture_byte"] == 200
    assert "texture_bytes" in render.params["unsupported"]  # the runner samples no textures
    plain = simulate(make(texture_coef=None))  # no texture_bytes: no term, no coefficient needed
    assert plain.trace[(plain.trace.frame == 0) & (plain.trace.task == "render0")].end_ns.item() == 400
    with pytest.raises(InputError, match=r"gpus\[0\].costs.mesh.ns_per_texture_byte"):
        simulate(make({"passes": [{"name": "p", "kind": "mesh", "triangles": 800,
                                   "texture_bytes": 400}]}, texture_coef=None))


def test_sort_last_holds_whole_sections():
    """3 sections of 4000, 4000 and 1000 bytes on 2 GPUs: GPU 0 holds a and b (8000 B + its
    320 B of targets + 384 B of receive buffers), GPU 1 c (1000 + 384). Sort-first holds all."""
    exp = make({"sections": SECTIONS})
    assert exp.scene.dataset_bytes == 9000 and exp.scene.objects == 3
    report = memory_report(build_program(exp), exp)
    assert report["gpu0"]["sections"] == ["a", "b"] and report["gpu0"]["used_bytes"] == 8704
    assert report["gpu1"]["sections"] == ["c"] and report["gpu1"]["used_bytes"] == 1384
    first = make({"sections": SECTIONS}, schedule="sort_first")
    assert memory_report(build_program(first), first)["gpu1"]["sections"] == ["a", "b", "c"]
    r = simulate(make({"sections": SECTIONS}))  # work follows the objects: 2/1 of 800 triangles
    f0 = r.trace[r.trace.frame == 0].set_index("task")
    assert (f0.loc["render0", "end_ns"], f0.loc["render1", "end_ns"]) == (533, 267)


def test_overflow_names_the_sections_that_fit():
    """5000 B GPUs: GPU 0 has 4296 B beside its buffers: section a (4000) fits, b does not."""
    exp = make({"sections": SECTIONS}, memory=5000)
    with pytest.raises(InputError, match=r"sections a, b, of which only the first 1 fit \(a\)") as err:
        check_memory(build_program(exp), exp)
    assert err.value.field == "scene.sections"
    other = make({"sections": SECTIONS}, memory=5000, object_counts=[1, 2])
    with pytest.raises(InputError, match=r"gpu1 .* sections b, c, of which only the first 1 fit \(b\)"):
        check_memory(build_program(other), other)


@pytest.mark.parametrize("extra, field", [
    ({"sections": SECTIONS, "dataset_bytes": 10}, "scene.dataset_bytes"),
    ({"sections": SECTIONS, "objects": 2}, "scene.objects"),
    ({"sections": [SECTIONS[0], SECTIONS[0]]}, r"scene.sections\[1\].name"),
    ({"sections": [{"name": "a", "geometry_bytes": -1}]}, r"scene.sections\[0\].geometry_bytes"),
    ({"sections": [{"name": "a", "geometry_bytes": 1, "textures": 2}]}, r"scene.sections\[0\].textures")])
def test_sections_bad_input(extra, field):
    with pytest.raises(InputError, match=field):
        make(extra)
