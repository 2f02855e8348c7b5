"""The cost model's optional terms: a profile may leave them out (then they are 0)."""
from __future__ import annotations

from mgpusim.costs import CostModel, pass_work
from mgpusim.profile import parse_profile
from mgpusim.scene import PassSpec
from tests.conftest import profile_dict


def test_mesh_squared_triangles_cost_only_where_the_profile_has_them():
    spec = PassSpec("mesh", "mesh", {"triangles": 1000})
    work = pass_work(spec, 100, 0.5)
    assert work["triangle"] == 500 and work["triangle_squared"] == 250_000
    data = profile_dict(gpus=1)
    data["gpus"][0]["costs"]["mesh"] = {"fixed_ns": 10, "ns_per_triangle": 2.0, "ns_per_pixel": 0.0}
    linear = CostModel(parse_profile(data, "<t>")).pass_ns(0, "mesh", work)
    assert linear == 10 + 2 * 500
    data["gpus"][0]["costs"]["mesh"]["ns_per_triangle_squared"] = 0.001
    assert CostModel(parse_profile(data, "<t>")).pass_ns(0, "mesh", work) == linear + 250
