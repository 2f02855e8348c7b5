"""Each pass of the library produces the right pixels / values on lavapipe."""
from __future__ import annotations

import numpy as np
import pytest

from mgpusim.real.passes.particle_update import ParticleUpdate, initial_state, reference_update
from mgpusim.real.passes.standalone import (
    CompositeSortFirst,
    CompositeSortLast,
    FragmentLoop,
    Mesh,
    ParticleRender,
    torus_mesh,
)
from mgpusim.real.vulkan.buffers import DEPTH_FORMAT
from mgpusim.real.vulkan.copies import download, upload

pytestmark = pytest.mark.vulkan


def _rgba(gpu, image):
    return download(gpu, image).reshape(image.height, image.width, 4)


def test_fragment_loop_colours_match_uv(gpu):
    w, h, n = 32, 24, 50
    p = FragmentLoop(gpu, w, h, n)
    gpu.run(p.queue, p.record)
    img = _rgba(gpu, p.target.color).astype(float) / 255
    factor = (np.float32(1.00001) * np.float32(0.999998)) ** n
    xs, ys = (np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h
    assert np.allclose(img[..., 0], xs[None, :] * factor, atol=1.5 / 255)
    assert np.allclose(img[..., 1], ys[:, None] * factor, atol=1.5 / 255)
    assert np.all(img[..., 3] == 1.0)
    p.destroy()


def test_fragment_loop_tile_matches_full_frame(gpu):
    full = FragmentLoop(gpu, 32, 24, 10)
    tile = FragmentLoop(gpu, 32, 8, 10, frame=(32, 24), offset=(0, 8))
    gpu.run("graphics", full.record)
    gpu.run("graphics", tile.record)
    a, b = _rgba(gpu, full.target.color), _rgba(gpu, tile.target.color)
    assert np.abs(a[8:16].astype(int) - b.astype(int)).max() <= 1
    full.destroy()
    tile.destroy()


def test_torus_mesh_has_exact_triangle_count():
    for t in (1, 7, 100, 1001):
        assert torus_mesh(t).shape == (3 * t, 6)


def test_mesh_covers_pixels_and_writes_depth(gpu):
    p = Mesh(gpu, 48, 48, 2000)
    gpu.run(p.queue, p.record)
    colour = _rgba(gpu, p.target.color)
    depth = download(gpu, p.target.depth).view(np.uint16).reshape(48, 48)
    covered = colour[..., 3] == 255
    assert 0.05 < covered.mean() < 0.9
    assert np.all(depth[covered] < 65535) and np.all(depth[~covered] == 65535)
    p.destroy()


def test_sort_first_places_each_tile(gpu):
    w, h, n = 16, 20, 3
    p = CompositeSortFirst(gpu, w, h, n)
    colours = [(255, 0, 0, 255), (0, 255, 0, 255), (10, 20, 250, 255)]
    for img, c in zip(p.inputs, colours):
        upload(gpu, img, np.tile(np.array(c, np.uint8), img.width * img.height))
    gpu.run(p.queue, p.record)
    out = _rgba(gpu, p.target.color)
    assert [rows for _, rows in p.tiles] == [6, 6, 8]  # the last tile takes the remainder
    for (y0, rows), c in zip(p.tiles, colours):
        assert np.all(out[y0:y0 + rows] == c), f"tile at row {y0}"
    p.destroy()


def test_sort_last_keeps_nearest_fragment(gpu):
    w, h, n = 16, 12, 3
    p = CompositeSortLast(gpu, w, h, n)
    rng = np.random.default_rng(1)
    # distinct depths per pixel: a random permutation of three well-separated levels
    levels = np.array([10000, 30000, 50000], np.uint16)
    depths = levels[np.argsort(rng.random((n, h, w)), axis=0)]
    colours = rng.integers(0, 256, (n, h, w, 4), dtype=np.uint8)
    for i, (c_img, d_img) in enumerate(p.inputs):
        assert d_img.format_name == DEPTH_FORMAT
        upload(gpu, c_img, colours[i])
        upload(gpu, d_img, depths[i])
    gpu.run(p.queue, p.record)
    out = _rgba(gpu, p.target.color)
    nearest = np.argmin(depths, axis=0)
    expected = np.take_along_axis(colours, nearest[None, ..., None], axis=0)[0]
    assert np.array_equal(out, expected)
    out_depth = download(gpu, p.target.depth).view(np.uint16).reshape(h, w)
    assert np.abs(out_depth.astype(int) - depths.min(axis=0)).max() <= 1
    p.destroy()


@pytest.mark.parametrize("dt", [1 / 60, 0.7])
def test_particle_update_matches_numpy(gpu, dt):
    n = 300  # not a multiple of the 64-wide workgroup
    state0 = initial_state(n, seed=3)
    p = ParticleUpdate(gpu, n, dt=dt, state=state0)
    ref = state0
    for _ in range(2):
        gpu.run("compute", p.record)
        ref, calc, verts = reference_update(ref, dt)
    got_state = download(gpu, p.state).view(np.float32).reshape(n, 4, 4)
    got_calc = download(gpu, p.calc).view(np.float32).reshape(n, 2, 4)
    got_verts = download(gpu, p.vertices).view(np.float32).reshape(n, 12, 4)
    if dt > 0.5:
        assert (ref[:, 3, 0] == 0).any(), "some particles must respawn"
    np.testing.assert_allclose(got_state, ref, atol=1e-5)
    np.testing.assert_allclose(got_calc, calc, atol=1e-5)
    np.testing.assert_allclose(got_verts, verts, atol=1e-5)
    p.destroy()


def test_particle_render_draws_sprites(gpu):
    p = ParticleRender(gpu, 64, 64, 500)
    gpu.run(p.queue, p.record)
    out = _rgba(gpu, p.target.color)
    lit = out[..., 0] > 0
    assert 0.001 < lit.mean() < 0.9
    p.destroy()


def test_failed_pipeline_creation_leaves_nothing_behind(gpu):
    """The second shader is missing: the first module and the layouts are destroyed anyway
    (the session's validation-layer check would report leaked objects at device destruction)."""
    from mgpusim.real.vulkan.pipelines import RenderTarget, graphics_pipeline

    target = RenderTarget(gpu, 8, 8, depth=False)
    try:
        with pytest.raises(FileNotFoundError):
            graphics_pipeline(gpu, target, "quad.vert", "no_such_shader.frag")
    finally:
        target.destroy()


def test_present_copies_the_frame_into_the_displayed_image(gpu):
    from mgpusim.real.passes.standalone import Present
    p = Present(gpu, 24, 16)
    pixels = np.random.default_rng(2).integers(0, 256, (16, 24, 4), dtype=np.uint8)
    upload(gpu, p.frame, pixels)
    gpu.run(p.queue, p.record)
    assert np.array_equal(_rgba(gpu, p.display), pixels)
    p.destroy()


def test_microbenchmarks_record_the_runners_passes(gpu):
    """One pass library: what `mgpusim measure` times is the runner's own pass object."""
    from mgpusim.real.passes import recorders as fp
    built = [(FragmentLoop(gpu, 16, 16, 5), fp.FragmentLoopTile), (Mesh(gpu, 16, 16, 50), fp.MeshShare),
             (CompositeSortFirst(gpu, 16, 16, 2), fp.CompositeInto),
             (CompositeSortLast(gpu, 16, 16, 2), fp.CompositeInto)]
    for p, kind in built:
        assert type(p.work) is kind
        # the composite loads the frame the primary rendered; the renders clear their targets
        assert p.work.targets[0].clear is (kind is not fp.CompositeInto)
        p.destroy()


@pytest.mark.parametrize("inputs", [1, 2, 4])
def test_filter_combines_its_inputs_as_the_shader_says(gpu, inputs):
    """fract(last input + (other inputs + the loop's uv) / 16), per pixel: what the temporal
    pass and the pipelining chain compute."""
    from mgpusim.real.passes.standalone import FilterPass

    w, h, n = 32, 24, 20
    p = FilterPass(gpu, w, h, n, inputs)
    gpu.run(p.queue, p.record)
    out = _rgba(gpu, p.target.color).astype(float) / 255
    ramp = ((np.arange(w * h * 4) % 251) / 255).reshape(h, w, 4)[..., :3]
    factor = (np.float32(1.00001) * np.float32(0.999998)) ** n
    xs, ys = (np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h
    loop = np.stack([np.broadcast_to(xs[None, :] * factor, (h, w)),
                     np.broadcast_to(ys[:, None] * factor, (h, w)), np.full((h, w), 0.5)], -1)
    expected = np.mod(ramp + ((inputs - 1) * ramp + loop) / 16, 1.0)
    wrapped = np.abs(out[..., :3] - expected)
    assert np.minimum(wrapped, 1 - wrapped).max() <= 2 / 255
    assert np.all(out[..., 3] == 1.0)
    p.destroy()


def test_stereo_eyes_see_the_scene_from_two_places(gpu):
    """XR's eye cameras: the two eyes differ, by a small horizontal shift of the torus."""
    eyes = []
    for eye in (0, 1):
        p = Mesh(gpu, 64, 48, 3000, eye=eye)
        gpu.run(p.queue, p.record)
        eyes.append(_rgba(gpu, p.target.color)[..., 3] == 255)
        p.destroy()
    assert not np.array_equal(*eyes)
    cols = [np.nonzero(e.any(axis=0))[0] for e in eyes]
    assert cols[0][0] > cols[1][0]  # the left eye sees the torus further right


def test_vmgpus_sphere_culls_only_faces_that_the_depth_test_hides(gpu):
    """Culling back faces leaves the picture as it is (the depth test hid them) and draws as
    many pixels as the model's coverage of that view says: the runner culls the faces the
    model counts as culled, not the front ones."""
    from mgpusim.model.geometry import MeshView, coverage
    w, h, t = 96, 64, 4000
    drawn = {}
    for cull in ("none", "back"):
        p = Mesh(gpu, w, h, t, shape="sphere", cull=cull)
        gpu.run(p.queue, p.record)
        drawn[cull] = _rgba(gpu, p.target.color)
        p.destroy()
    assert np.abs(drawn["none"].astype(int) - drawn["back"].astype(int)).max() <= 1
    covered = (drawn["back"][..., 3] == 255).sum()
    model = coverage(MeshView(t, (w, h), shape="sphere", cull="back")).fragments
    assert covered == pytest.approx(model, rel=0.03)
    lit = drawn["back"][..., 0][drawn["back"][..., 3] == 255]
    assert lit.min() >= int(0.15 * 255) - 1 and lit.max() > 200  # vmgpu's ambient + light


def test_a_sphere_share_draws_only_its_triangles(gpu):
    """Sort-last's share of the sphere: the first half's pixels and the second's together are
    the whole sphere's (vmgpu's index ranges, split in order)."""
    w, h, t = 64, 64, 2000
    whole = Mesh(gpu, w, h, t, shape="sphere", cull="back")
    halves = [Mesh(gpu, w, h, t, first=k * t // 2, count=t // 2, shape="sphere", cull="back")
              for k in (0, 1)]
    covered = []
    for p in (whole, *halves):
        gpu.run(p.queue, p.record)
        covered.append(_rgba(gpu, p.target.color)[..., 3] == 255)
        p.destroy()
    assert covered[1].any() and covered[2].any() and not np.array_equal(covered[1], covered[2])
    assert np.array_equal(covered[1] | covered[2], covered[0])


def test_a_mesh_of_an_unknown_shape_is_refused(gpu):
    from mgpusim.model.errors import InputError
    with pytest.raises(InputError, match="shape"):
        Mesh(gpu, 16, 16, 100, shape="cube")
