"""Queues of one physical GPU sharing it (the shared_gpu effect): passes on two queues of one
GPU, or of two logical GPUs on one physical GPU, slow each other by the pair's overlap
efficiency; hand-computed timelines, the profile fields, and where the effect is on."""
from __future__ import annotations

import copy
from fractions import Fraction
from pathlib import Path

import pytest

from mgpusim import simulate
from mgpusim.model.errors import InputError
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import QueueRef
from mgpusim.schedules.experiment import parse_experiment
from mgpusim.sim.effects import choose_effects
from mgpusim.sim.executors import shares
from mgpusim.sim.simulation import build_program
from tests.conftest import experiment_dict, make_experiment, profile_dict


def capacity(profile, tags) -> Fraction:
    """What the pieces `tags` deliver together, in units of one alone."""
    return sum(shares(profile, tags), Fraction(0))


def _profile(overlap: dict | None = None, physical: int | None = None, gpus: int = 2) -> dict:
    prof = profile_dict(gpus=gpus)
    gpu = prof["gpus"][0]
    gpu["costs"]["particle_update"] = {"ns_per_particle": 1.0}
    gpu["costs"]["particle_render"] = {"fixed_ns": 100, "ns_per_particle": 0.0, "ns_per_pixel": 0.0}
    if overlap is not None:
        gpu["queue_overlap"] = overlap
    if physical is not None:
        gpu["physical"] = physical
    return prof


def _spans(result, frame: int = 0) -> dict[str, tuple[int, int]]:
    t = result.trace[result.trace.frame == frame].set_index("task")
    return {name: (int(r.start_ns), int(r.end_ns)) for name, r in t.iterrows()}


def _particles(prof: dict, **sched) -> object:
    """The primary renders a 32x10 fragment loop of 1 iteration (320 ns, `geometry`) while its
    compute queue updates 1000 particles (1000 ns); the draw waits for the update."""
    data = experiment_dict("particles", gpus=1, width=32, height=10, particles=1000,
                           particle_gpu=0, policy="wait", **sched)
    data["scene"]["passes"] = [{"name": "geometry", "kind": "fragment_loop", "iterations": 1}]
    return parse_experiment(data, "t", profile=parse_profile(copy.deepcopy(prof), "p"))


def test_two_queues_of_one_gpu_share_it_by_their_efficiency():
    # independent queues (no queue_overlap): both start at 0 and run at full speed
    free = _spans(simulate(_particles(_profile())))
    assert free["render.geometry"] == (0, 320) and free["particle_update"] == (0, 1000)
    # efficiency 1: no gain from overlap, each at half speed while both run: the render's
    # 320 ns take 640; the update did 320 by then and runs its last 680 alone (ends 1320)
    one = simulate(_particles(_profile({"graphics_compute": 1.0})))
    s = _spans(one)
    assert s["render.geometry"] == (0, 640) and s["particle_update"] == (0, 1320)
    assert "shared_gpu" in one.summary["modelled_effects"]
    assert one.summary["effects"]["gpu_contention"] is True
    # efficiency 1.5: each at 3/4 speed together: 320 / 0.75 = 426.67 -> 427; update 320 done,
    # 680 alone: ends at 1106.67 -> 1107
    s = _spans(simulate(_particles(_profile({"graphics_compute": 1.5}))))
    assert s["render.geometry"] == (0, 427) and s["particle_update"] == (0, 1107)


def test_update_on_the_graphics_queue_is_back_to_back_whatever_the_efficiency():
    prof = _profile({"graphics_compute": 1.0})
    s = _spans(simulate(_particles(prof, update_queue="graphics")))
    assert s["particle_update"] == (0, 1000) and s["render.geometry"] == (1000, 1320)
    assert "shared_gpu" not in simulate(_particles(prof, update_queue="graphics")).summary["modelled_effects"]


def test_two_logical_gpus_on_one_physical_gpu_take_turns():
    # sort-first: 8x4, 2 tiles of 16 px x 100 iterations = 1600 ns each, at once on two GPUs
    apart = _spans(simulate(make_experiment(_profile(), gpus=2, iterations=100)))
    assert apart["render0"] == (0, 1600) and apart["render1"] == (0, 1600)
    shared = simulate(make_experiment(_profile(physical=0), gpus=2, iterations=100))
    s = _spans(shared)
    assert s["render0"] == (0, 3200) and s["render1"] == (0, 3200)  # devices = 1 by default
    assert "gpu0.exec" in shared.summary["utilization"] or shared.links["channel"].eq("gpu0.exec").any()
    s = _spans(simulate(make_experiment(_profile({"devices": 1.6}, physical=0), gpus=2, iterations=100)))
    assert s["render0"] == (0, 2000) and s["render1"] == (0, 2000)


def test_effect_is_on_only_where_a_gpu_runs_two_queues_that_interfere():
    plain = make_experiment(_profile(), gpus=2)
    assert "shared_gpu" not in choose_effects(build_program(plain), plain.profile)
    perfect = make_experiment(_profile({"graphics_compute": 2.0, "graphics_transfer": 2.0}), gpus=2)
    assert "shared_gpu" not in choose_effects(build_program(perfect), perfect.profile)
    one_queue = make_experiment(_profile({"graphics_transfer": 1.0}), gpus=1)
    assert "shared_gpu" not in choose_effects(build_program(one_queue), one_queue.profile)
    copies = make_experiment(_profile({"graphics_transfer": 1.0}), gpus=2)  # gpu0 uploads on transfer
    assert "shared_gpu" in choose_effects(build_program(copies), copies.profile)
    assert "shared_gpu" not in choose_effects(build_program(copies), copies.profile, "queues")
    lava = _profile(physical=0)
    lava["host"]["gpus_share_cpu"] = True  # the host's cores are the shared resource there
    lp = make_experiment(lava, gpus=2)
    chosen = choose_effects(build_program(lp), lp.profile)
    assert "shared_executor" in chosen and "shared_gpu" not in chosen


def test_copy_on_the_copy_engine_shares_by_graphics_transfer():
    # sort-first on 2 GPUs: the primary's transfer queue uploads while its graphics queue renders
    free = simulate(make_experiment(_profile(), gpus=2, iterations=100, frames=6))
    slow = simulate(make_experiment(_profile({"graphics_transfer": 1.0}), gpus=2, iterations=100, frames=6))
    assert slow.summary["frame_time_ms"] > free.summary["frame_time_ms"]
    same = simulate(make_experiment(_profile({"graphics_transfer": 2.0}), gpus=2, iterations=100, frames=6))
    assert same.trace.equals(free.trace)


def test_capacity_of_several_queues():
    prof = parse_profile(_profile({"graphics_compute": 1.5, "graphics_transfer": 1.8,
                                   "compute_transfer": 1.2}, gpus=1), "p")
    g, c, x = ((QueueRef(0, fam), kind) for fam, kind in
               (("graphics", "fragment_loop"), ("compute", "particle_update"), ("transfer", "copy")))
    assert capacity(prof, (g,)) == 1
    assert capacity(prof, (g, c)) == Fraction(3, 2)
    # three at once: 1 + 2 x mean gain (0.5, 0.8, 0.2) = 2
    assert capacity(prof, (g, c, x)) == 2
    worst = parse_profile(_profile({"graphics_compute": 0.5, "graphics_transfer": 0.5,
                                    "compute_transfer": 0.5}, gpus=1), "p")
    assert capacity(worst, (g, c, x)) == Fraction(1, 2)  # never below the worst pair


def test_a_pass_kinds_own_efficiency_wins_for_the_pairs_it_is_in():
    # the draw blends (memory-bound): a copy hurts it more than the fragment loop
    prof = _profile({"graphics_transfer": 1.9})
    prof["gpus"][0]["queue_overlap"]["particle_render"] = {"graphics_transfer": 1.2}
    p = parse_profile(prof, "p")
    draw, loop = (QueueRef(0, "graphics"), "particle_render"), (QueueRef(0, "graphics"), "fragment_loop")
    copy_ = (QueueRef(0, "transfer"), "copy")
    assert capacity(p, (draw, copy_)) == Fraction(6, 5) and capacity(p, (loop, copy_)) == Fraction(19, 10)
    # a profile with only a kind's own table still turns the effect on where that kind overlaps
    only = _profile()
    only["gpus"][0]["queue_overlap"] = {"fragment_loop": {"graphics_transfer": 1.0}}
    exp = make_experiment(only, gpus=2)
    assert "shared_gpu" in choose_effects(build_program(exp), exp.profile)
    mesh = make_experiment(only, schedule="sort_last", gpus=2)  # meshes, not fragment loops
    assert "shared_gpu" not in choose_effects(build_program(mesh), mesh.profile)


def test_fast_forward_and_levels_with_a_shared_gpu():
    exp = _particles(_profile({"graphics_compute": 1.3}), frames=300)
    on, off = simulate(exp), simulate(exp, fast_forward=False)
    assert on.summary["fast_forward"]["used"] is True
    assert on.trace.equals(off.trace) and on.frames.equals(off.frames)
    analytic = simulate(exp, fidelity="analytic").summary
    assert any(a.startswith("shared_gpu") for a in analytic["effects"]["analytic_approximations"])
    assert analytic["frame_time_ms"] <= on.summary["frame_time_ms"]  # an optimistic bound


@pytest.mark.parametrize("overlap, field, message", [
    ({"graphics_compute": 2.5}, "graphics_compute", "<= 2"),
    ({"graphics_compute": 0}, "graphics_compute", "> 0"),
    ({"graphics_compte": 1.2}, "graphics_compte", "did you mean 'graphics_compute'"),
])
def test_bad_queue_overlap_names_the_field(overlap, field, message):
    with pytest.raises(InputError, match=message) as err:
        parse_profile(_profile(overlap), "p.toml")
    assert f"queue_overlap.{field}" in str(err.value)


def test_logical_gpus_of_one_physical_gpu_describe_it_alike():
    prof = profile_dict(gpus=1)
    first = dict(prof["gpus"][0], queue_overlap={"graphics_compute": 1.2})
    second = dict(prof["gpus"][0], physical=0, queue_overlap={"graphics_compute": 1.4})
    prof["gpus"] = [first, second]
    with pytest.raises(InputError, match="physical GPU 0") as err:
        parse_profile(prof, "p.toml")
    assert "gpus[1].queue_overlap" in str(err.value)
    with pytest.raises(InputError, match="physical"):
        parse_profile(_profile(physical=-1), "p.toml")


def test_a_run_on_one_gpu_is_compared_only_with_a_profile_that_says_so(tmp_path):
    from mgpusim.validation.measured_check import check_physical_gpus

    one_gpu = {"gpus": [{"name": "gpu0", "physical_index": 0}, {"name": "gpu1", "physical_index": 0}]}
    apart = make_experiment(_profile(), gpus=2)
    with pytest.raises(InputError, match="ran on one physical GPU") as err:
        check_physical_gpus(one_gpu, apart, "machine.json")
    assert "gpus[1].physical" in str(err.value)
    check_physical_gpus(one_gpu, make_experiment(_profile(physical=0), gpus=2), "machine.json")
    two_gpus = {"gpus": [{"physical_index": 0}, {"physical_index": 1}]}
    check_physical_gpus(two_gpus, apart, "machine.json")
    with pytest.raises(InputError, match="different physical GPUs"):
        check_physical_gpus(two_gpus, make_experiment(_profile(physical=0), gpus=2), "machine.json")
    check_physical_gpus({"gpus": [{"name": "gpu0"}, {"name": "gpu1"}]}, apart, "m")  # older record
    lava = _profile()
    lava["host"]["gpus_share_cpu"] = True  # lavapipe: the CPU is what they share
    check_physical_gpus(one_gpu, make_experiment(lava, gpus=2), "machine.json")


def test_h100_queues_study_configurations_model_the_sharing():
    """The NVIDIA particle configurations: where the update runs decides whether the one GPU's
    queues share it; the second logical GPU is on the same physical GPU."""
    from pathlib import Path

    from mgpusim.model.overrides import parse_overrides
    from mgpusim.studies import load_study

    root = Path(__file__).resolve().parents[1]
    study = load_study(root / "experiments" / "h100" / "queues.toml")
    what_if = parse_overrides(["profile.gpus.0.queue_overlap.graphics_compute=1.2"])
    seen = {}
    for entry in study.entries():
        exp = entry.load(study.profile, [f"{k}={v}" for k, v in what_if.items()])
        prog = build_program(exp)
        seen[entry.name] = ("shared_gpu" in choose_effects(prog, exp.profile), exp.profile.shares_physical())
    assert seen["p2m_graphics"] == (False, False) and seen["p4m_graphics"] == (False, False)
    assert seen["p2m_compute"] == (True, False) and seen["p4m_compute"] == (True, False)
    assert all(seen[n] == (True, True) for n in ("p2m_2dev_wait", "p2m_2dev_new_wait", "p2m_2dev_nohost"))


def test_work_that_takes_turns_is_not_sped_up_by_a_copy_beside_it():
    # three VkDevices' renders on one GPU take turns at their pair's 0.5; a copy on the copy
    # engine (graphics_transfer 2: another unit) runs beside them at full speed and leaves the
    # renders' turn-taking as it was (the mean over mixed pairs would have given every piece
    # 1 + 3 x mean(-0.5, -0.5, -0.5, 1, 1, 1) / 4 = 1.75 / 4, the renders 2.6x faster)
    prof = parse_profile(_profile({"devices": 0.5, "graphics_transfer": 2.0}, physical=0, gpus=3), "p")
    renders = tuple((QueueRef(d, "graphics"), "mesh") for d in range(3))
    up = (QueueRef(0, "transfer"), "copy")
    assert shares(prof, renders) == (Fraction(1, 6),) * 3
    assert shares(prof, (*renders, up)) == (Fraction(1, 6),) * 3 + (Fraction(1),)
    assert capacity(prof, (*renders, up)) == Fraction(3, 2)
    # a copy that halves what a render does beside it (1.5): both classes at 3/4 of their own
    half = parse_profile(_profile({"devices": 0.5, "graphics_transfer": 1.5}, physical=0, gpus=3), "p")
    assert shares(half, (*renders, up)) == (Fraction(1, 8),) * 3 + (Fraction(3, 4),)


def test_a_render_beside_a_copy_keeps_its_turn_taking_speed():
    # sort-first on 2 logical GPUs of one GPU (devices 1: they take turns): 2 tiles of 1600 ns
    # each take 3200 together; the primary's upload of the previous frame's tile on the copy
    # engine (graphics_transfer 2) overlaps them and must not shorten them
    prof = _profile({"devices": 1.0, "graphics_transfer": 2.0}, physical=0)
    r = simulate(make_experiment(prof, gpus=2, iterations=100, frames=6))
    t = r.trace[r.trace.frame == 4].set_index("task")
    renders = [int(t.loc[name].end_ns - t.loc[name].start_ns) for name in ("render0", "render1")]
    assert renders == [3200, 3200]


def test_three_and_four_vkdevices_take_turns_as_two_do_on_the_h200():
    """Measured (data/vmgpu/h200_x1/devices_at_once): N VkDevices' draws at once on one H200.
    The pair's efficiency, measured on 2 devices, predicts 3 and 4 through the class rule
    (N pieces taking turns deliver the pair's efficiency, each 1 / N of it)."""
    import pandas as pd

    table = pd.read_parquet(Path(__file__).parent.parent / "data/vmgpu/h200_x1/devices_at_once/passes.parquet")
    keys = ["pass", "triangles", "iterations", "width", "height"]
    slowest = (table.fillna({"triangles": 0, "iterations": 0})
               .groupby([*keys, "gpus", "repetition"]).duration_ns.max()
               .groupby([*keys, "gpus"]).median().unstack("gpus"))
    long = slowest[slowest[1] > 2e6]  # passes long enough to overlap (the short loop ran alone)
    ratios: dict[int, list[float]] = {3: [], 4: []}
    for _key, row in long.iterrows():
        pair = 2 * row[1] / row[2]
        prof = parse_profile(_profile({"devices": min(pair, 1.0)}, physical=0, gpus=4), "p")
        for n in (3, 4):
            speed = shares(prof, tuple((QueueRef(d, "graphics"), "mesh") for d in range(n)))[0]
            ratios[n].append(row[n] / (row[1] / float(speed)))
    median = {n: sorted(r)[len(r) // 2] for n, r in ratios.items()}
    assert len(long) >= 6
    assert abs(median[3] - 1) < 0.05 and abs(median[4] - 1) < 0.05
