"""The mesh's coverage (what a view of the torus rasterizes) and the placed mesh work terms."""
import math
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

import pytest

from mgpusim.model.costs import CostModel
from mgpusim.model.errors import InputError
from mgpusim.model.geometry import MeshView, Placement, coverage, mesh_placement, torus_mesh
from mgpusim.model.profile import load_profile
from mgpusim.model.scene import PassSpec
from mgpusim.model.work_terms import pass_work
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.program import build_program

FRAME = (256, 192)


def test_shares_partition_the_mesh():
    """Sort-last shares draw disjoint triangles: their counts, areas and edges add up to the
    whole mesh's, and the half that faces the camera covers more pixels than the other."""
    whole = coverage(Placement(FRAME).mesh_view(20_000))
    halves = [coverage(Placement(FRAME, share=(k, 2)).mesh_view(20_000)) for k in range(2)]
    assert sum(h.triangles for h in halves) == whole.triangles == 20_000
    assert sum(h.fragments for h in halves) == pytest.approx(whole.fragments)
    assert sum(h.edge for h in halves) == pytest.approx(whole.edge)
    assert halves[0].fragments > 1.2 * halves[1].fragments


def test_half_eye_views_cull_what_they_do_not_see():
    """Each column of an eye reaches only part of the triangles (more than half together:
    triangles on the seam reach both) and their fragments partition the eye's."""
    eye = coverage(Placement(FRAME, eye=0).mesh_view(20_000))
    cols = [coverage(Placement(FRAME, (x, 0, 128, 192), eye=0).mesh_view(20_000)) for x in (0, 128)]
    assert all(0.3 * eye.triangles < c.triangles < 0.7 * eye.triangles for c in cols)
    assert eye.triangles < sum(c.triangles for c in cols) < 1.1 * eye.triangles
    assert sum(c.fragments for c in cols) == pytest.approx(eye.fragments)


def test_coverage_scales_with_resolution_and_tessellation():
    """Fragments go as the frame's pixels; a triangle's linear size as sqrt(pixels / T)."""
    small = coverage(MeshView(20_000, (128, 96)))
    big = coverage(MeshView(20_000, (512, 384)))
    assert big.fragments == pytest.approx(16 * small.fragments, rel=1e-9)
    assert big.edge == pytest.approx(4 * small.edge, rel=1e-9)
    fine = coverage(MeshView(80_000, (128, 96)))
    assert fine.fragments == pytest.approx(small.fragments, rel=0.02)
    assert fine.edge == pytest.approx(2 * small.edge, rel=0.05)


def test_large_meshes_are_sampled_not_generated():
    """Above the sample size the coverage comes from a smaller torus, scaled: the same areas,
    edges as sqrt(T), and no multi-GB vertex array."""
    sampled = coverage(MeshView(4_000_000, FRAME))
    ref = coverage(MeshView(200_000, FRAME))
    assert sampled.triangles == 4_000_000
    assert sampled.fragments == pytest.approx(ref.fragments)
    assert sampled.edge == pytest.approx(ref.edge * math.sqrt(20))


def test_torus_has_exactly_the_triangles_asked():
    for t in (1, 7, 2000, 20_001):
        assert torus_mesh(t).shape == (3 * t, 6)
    with pytest.raises(InputError, match="triangles"):
        torus_mesh(0)


def test_placed_mesh_terms_and_older_profiles():
    """A placement adds the placed terms; a profile without their coefficients costs the pass
    as before (triangles and pixels), one with them charges them."""
    spec = PassSpec("m", "mesh", {"triangles": 20_000})
    plain = pass_work(spec, 49_152)
    placed = pass_work(spec, 24_576, 1.0, Placement(FRAME, (0, 0, 128, 192), eye=1))
    assert set(placed) - set(plain) == {"visible_triangle", "triangle_edge", "fragment"}
    assert placed["visible_triangle"] < 20_000
    profile = load_profile("hardware_profiles/lavapipe_2core.toml")
    gpu = profile.gpus[0]
    plain_cost = {t: v for t, v in gpu.costs["mesh"].ns_per.items() if t in plain}
    gpu = replace(gpu, costs=MappingProxyType({**gpu.costs, "mesh": replace(
        gpu.costs["mesh"], ns_per=MappingProxyType(plain_cost))}))
    costs = CostModel(replace(profile, gpus=(gpu,) + profile.gpus[1:]))
    older = costs.pass_cost_ns(0, "mesh", placed)
    assert older == costs.pass_cost_ns(0, "mesh", {k: placed[k] for k in plain})
    mesh = replace(gpu.costs["mesh"], ns_per=MappingProxyType({**gpu.costs["mesh"].ns_per,
                                                               "visible_triangle": 10.0}))
    gpu = replace(gpu, costs=MappingProxyType({**gpu.costs, "mesh": mesh}))
    richer = CostModel(replace(profile, gpus=(gpu,) + profile.gpus[1:]))
    assert richer.pass_cost_ns(0, "mesh", placed) == pytest.approx(
        older + 10.0 * placed["visible_triangle"] / gpu.speed)


@pytest.mark.parametrize("text", ["share=2/2", "eye=up", "column=0/0", "row=1", "foo", "column=0/999"])
def test_bad_placements_name_the_field(text):
    with pytest.raises(InputError, match="place"):
        mesh_placement({"width": 256, "height": 192, "place": text})


def test_measured_placement_follows_the_schedules_rules():
    p = mesh_placement({"width": 257, "height": 192, "place": "eye=right;column=1/2;share=1/3"})
    assert p.rect == (128, 0, 129, 192) and p.eye == 1 and p.share == (1, 3)
    view = p.mesh_view(1000)
    assert (view.first, view.count) == (333, 333)  # the runner's T*k//n rule


def _renders(path, **overrides):
    exp = load_experiment(path, {f"schedule.{k}": v for k, v in overrides.items()})
    program = build_program(exp)
    return exp, [t for t in program.templates[0] if getattr(t, "kind", None) == "mesh"]


def test_schedules_place_their_meshes_where_the_runner_draws_them():
    """Sort-last GPU i's work counts the triangles the runner uploads for it; an XR half-eye
    view's the triangles of its columns of its eye (fewer than the mesh)."""
    exp, tasks = _renders("experiments/lavapipe/sort_last.toml", gpus=3)
    total = int(exp.scene.passes[0].param("triangles"))
    for i, task in enumerate(sorted(tasks, key=lambda t: t.queue.device)):
        assert task.work["visible_triangle"] == total * (i + 1) // 3 - total * i // 3
    _, views = _renders("experiments/lavapipe/xr.toml", gpus=4)
    assert len(views) == 4
    assert all(v.work["visible_triangle"] < v.work["triangle"] for v in views)
    by_view = {v.name: v.work for v in views}
    assert by_view["render0.tori"] != by_view["render2.tori"]  # left and right eyes differ


def test_a_placement_renders_its_rectangle_or_the_whole_frame():
    assert Placement(FRAME).pixels == 256 * 192
    assert Placement(FRAME, (128, 0, 128, 96)).pixels == 128 * 96


@pytest.mark.parametrize("frame", [(640, 480), (1920, 1080)])
def test_vmgpus_sphere_fills_the_frames_height_and_culling_keeps_its_front(frame):
    """The unit sphere seen from twice its radius with a 60-degree vertical field of view: its
    silhouette is a disc of the frame's height (pi/4 x H^2 pixels). Culled, only the faces
    turned to the camera are rasterized, and they cover that disc once; unculled, the far side
    too (twice the disc)."""
    w, h = frame
    disc = math.pi / 4 * h * h
    back = coverage(MeshView(100_000, frame, shape="sphere", cull="back"))
    none = coverage(MeshView(100_000, frame, shape="sphere"))
    assert back.fragments == pytest.approx(disc, rel=0.005)
    assert none.fragments == pytest.approx(2 * disc, rel=0.005)
    assert none.triangles == 100_000
    # the faces turned to a camera at twice the radius: a cap within 60 degrees of the view axis,
    # a quarter of the area; the UV sphere's triangles are largest there, so fewer by count
    assert 0.15 * 100_000 < back.triangles < 0.25 * 100_000
    assert back.edge < none.edge / 2


def test_culled_triangles_still_cost_their_vertex_work():
    spec = PassSpec("m", "mesh", MappingProxyType({"triangles": 50_000.0}), (),
                    MappingProxyType({"shape": "sphere", "cull": "back"}))
    culled = pass_work(spec, 256 * 192, 1.0, Placement(FRAME))
    drawn = pass_work(replace(spec, options=MappingProxyType({"shape": "sphere"})), 256 * 192, 1.0,
                      Placement(FRAME))
    assert culled["triangle"] == drawn["triangle"] == 50_000
    assert culled["visible_triangle"] < drawn["visible_triangle"] / 4
    assert culled["fragment"] == pytest.approx(drawn["fragment"] / 2, rel=0.01)


def test_the_torus_keeps_its_coverage_by_default():
    plain = coverage(MeshView(20_000, FRAME))
    assert coverage(MeshView(20_000, FRAME, shape="torus", cull="none")) == plain
    # culled, the torus loses the faces turned away from the runner's camera
    culled = coverage(MeshView(20_000, FRAME, cull="back"))
    assert 0.3 * plain.triangles < culled.triangles < 0.7 * plain.triangles


def test_shape_and_cull_are_read_and_checked_from_the_scene(tmp_path):
    exp = load_experiment("experiments/vmgpu/vmgpu.toml")
    mesh = exp.scene.passes[0]
    assert (mesh.option("shape"), mesh.option("cull")) == ("sphere", "back")
    plain = load_experiment("experiments/lavapipe/sort_last.toml").scene.passes[0]
    assert (plain.option("shape"), plain.option("cull")) == ("torus", "none")
    bad = tmp_path / "bad.toml"
    text = Path("experiments/vmgpu/vmgpu.toml").read_text().replace('shape = "sphere"', 'shape = "cube"')
    bad.write_text(text.replace('"../../hardware_profiles/', f'"{Path.cwd()}/hardware_profiles/'))
    with pytest.raises(InputError, match="shape"):
        load_experiment(bad)
