"""`advise`'s fast level shares one program and one recurrence model among the options that
differ only in their link (:meth:`Analytic.retimed`, :func:`prepare_like`): every row must be
the one the option gives loaded and simulated on its own."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from mgpusim import load_experiment
from mgpusim.advise import advisor
from mgpusim.advise.advisor import LINKS, evaluate, options, run_options
from mgpusim.cli import main
from mgpusim.model.costs import CostModel
from mgpusim.schedules.program import build_program
from mgpusim.sim.analytic import Analytic
from mgpusim.sim.effects import choose_effects, needed_on_links
from mgpusim.sim.simulation import link_free

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "hardware_profiles" / "pcie4_pair.toml"


@pytest.fixture(scope="module")
def frame(tmp_path_factory) -> Path:
    """Four passes, one reading the last frame (AFR carries it), on GTX-class GPUs."""
    tmp = tmp_path_factory.mktemp("frame")
    csv = tmp / "f.csv"
    csv.write_text("pass,queue,gpu_ms,reads,writes,bytes,pixel_share\n"
                   "shadow,graphics,1.5,,shadowmap,4194304,0\n"
                   "gbuffer,graphics,3.0,,gb,16588800,0.6\n"
                   "light,graphics,2.0,gb;shadowmap,hdr,16588800,1\n"
                   "taa,graphics,0.6,hdr;out,out,8294400,1\n")
    out = tmp / "f.toml"
    assert main(["frame", "import", str(csv), "--size", "1920x1080", "--profile", str(PROFILE),
                 "--out", str(out)]) == 0
    return out


def _same(a: dict, b: dict) -> bool:
    keys = set(a) - {"wall_s"}
    return keys == set(b) - {"wall_s"} and all(
        a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) for k in keys)


@pytest.mark.parametrize("fidelity", ["analytic", "queues"])
def test_rows_shared_over_links_are_each_options_own(frame, fidelity):
    opts = options(load_experiment(frame), max_gpus=3 if fidelity == "analytic" else 2, links=LINKS)
    items = [(i, o.overrides) for i, o in enumerate(opts)
             if fidelity == "analytic" or o.family != "pipelining" or "pass 2" in o.settings]
    shared = run_options(str(frame), {}, items, fidelity, 1)
    assert [r["option"] for r in shared] == [i for i, _ in items]  # in the items' order
    for item, row in zip(items, shared):
        advisor._loader.cache_clear()  # nothing shared: the option alone
        alone = evaluate(str(frame), {}, [item], fidelity)[0]
        assert _same(row, alone), (opts[item[0]].label, row, alone)


def _experiments(frame: Path, schedule: dict) -> list:
    return [load_experiment(frame, {"schedule": schedule, "profile.gpu_count": 2, **link.overrides})
            for link in LINKS]


@pytest.mark.parametrize("schedule", [
    {"name": "pipelining", "gpus": 2, "split_at": 2, "chunks": 3},
    {"name": "sort_first", "gpus": 2, "balance": True, "host_copy": True},
    {"name": "afr", "gpus": 2, "frames_in_flight": 2},
])
def test_one_program_and_retimed_model_per_link_family(frame, schedule):
    exps = _experiments(frame, schedule)
    first: list = []  # (link-free profile, experiment, program)
    for exp in exps:  # the program does not read a link's rate: one per link-free profile
        shape = link_free(exp.profile)
        program = build_program(exp)
        seen = next((f for f in first if f[0] == shape), None)
        if seen is None:
            first.append((shape, exp, program))
            continue
        _, source, theirs = seen
        assert program == theirs
        needed = choose_effects(program, exp.profile)
        assert needed_on_links(program, exp.profile, choose_effects(program, source.profile)) == needed
        chosen = choose_effects(program, exp.profile, "analytic")
        own = Analytic(program, CostModel(exp.profile), chosen)
        retimed = Analytic(program, CostModel(source.profile), chosen).retimed(CostModel(exp.profile))
        assert retimed.phases == own.phases
        assert retimed.approximations == own.approximations
    assert len(first) == 2  # PCIe (through host memory) and NVLink (a peer link)


def test_links_of_one_rate_are_one_run_handed_in_once(frame):
    """PCIe 3.0 x16 and 4.0 x8 carry one rate, so do 4.0 x16 and 5.0 x8: their options are one
    run of the model (each row is still the option's own: the test above compares them)."""
    same = advisor.SameRuns(str(frame))
    schedule = {"name": "afr", "gpus": 2, "frames_in_flight": 2}
    key = {link.name: same.key({"schedule": schedule, "profile.gpu_count": 2, **link.overrides})
           for link in LINKS}
    assert key["PCIe 3.0 x16"] == key["PCIe 4.0 x8"] and key["PCIe 4.0 x16"] == key["PCIe 5.0 x8"]
    assert len(set(key.values())) == len(LINKS) - 2
    assert same.key({"schedule": {**schedule, "gpus": 3}, "profile.gpu_count": 3, **LINKS[1].overrides}) \
        != key[LINKS[1].name]

    ran: list[int] = []

    class Counting(advisor.Workers):
        def submit(self, fn, *args):
            ran.extend(index for index, _ in args[2])
            return super().submit(fn, *args)

    items = [(k, {"schedule": schedule, "profile.gpu_count": 2, **link.overrides}) for k, link in enumerate(LINKS)]
    rows = advisor.Batch(Counting(1), str(frame), {}, items, "analytic").rows()
    assert [r["option"] for r in rows] == list(range(len(LINKS)))
    assert len(ran) == len(LINKS) - 2
    names = [link.name for link in LINKS]
    twin = rows[names.index("PCIe 4.0 x8")]
    assert {**twin, "option": 0} == {**rows[names.index("PCIe 3.0 x16")], "option": 0}


@pytest.mark.parametrize("schedule", [
    {"name": "afr", "gpus": 1, "frames_in_flight": 2},
    {"name": "afr", "gpus": 3, "frames_in_flight": 3, "temporal_pass": "taa", "history_bytes": 8294400},
    {"name": "afr", "gpus": 2, "frames_in_flight": 2, "cpu_frame_us": 500.0},
    {"name": "afr", "gpus": 2, "frames_in_flight": 2, "refresh_hz": 144.0},
])
def test_an_afr_program_at_another_cadence_is_the_one_built_at_it(frame, schedule):
    from mgpusim.schedules.afr import with_pace
    paced = [load_experiment(frame, {"schedule": {**schedule, "pace_us": pace}, "profile.gpu_count": 3})
             for pace in (1234.567, 2000.0, 7.001)]
    first = build_program(paced[0])
    for exp in paced[1:]:
        assert with_pace(first, exp.schedule.opt("pace_us")) == build_program(exp)
    with pytest.raises(ValueError, match="pace.gap"):
        with_pace(build_program(load_experiment(frame, {"schedule": schedule, "profile.gpu_count": 3})), 10.0)


def test_paced_rows_shared_over_links_and_cadences_are_each_options_own(frame):
    opts = [o for o in options(load_experiment(frame), max_gpus=3, links=LINKS) if o.family == "AFR"]
    items = [(k, advisor.paced(o, 0, pace).overrides) for k, (o, pace) in
             enumerate((o, pace) for o in opts for pace in (4100.0, 4141.0 + o.gpus, 4182.5))]
    shared = run_options(str(frame), {}, items, "analytic", 1)
    assert [r["option"] for r in shared] == [i for i, _ in items]
    for item, row in zip(items, shared):
        advisor._loader.cache_clear()
        alone = evaluate(str(frame), {}, [item], "analytic")[0]
        assert _same(row, alone), (item, row, alone)


def test_an_afr_option_at_several_cadences_builds_one_program_per_link_family(frame, monkeypatch):
    import mgpusim.sim.simulation as simulation
    built: list[str] = []
    real = simulation.build_program
    monkeypatch.setattr(simulation, "build_program", lambda exp: built.append(exp.file) or real(exp))
    afr = next(o for o in options(load_experiment(frame), max_gpus=2, links=LINKS) if o.family == "AFR")
    items = [(k, {**advisor.paced(afr, 0, pace).overrides, **link.overrides})
             for k, (link, pace) in enumerate((link, pace) for link in LINKS for pace in (4100.0, 4177.0))]
    advisor._loader.cache_clear()
    run_options(str(frame), {}, items, "analytic", 1)
    assert len(built) == 2  # PCIe (through host memory) and NVLink (a peer link)


def test_full_fidelity_loads_are_load_experiments_what_ifs_and_all(frame):
    """At full fidelity an option is the experiment load_experiment gives (its what-ifs
    recorded), on a profile loaded once per set of profile overrides; an override the model
    never reads is still refused as `simulate` refuses it."""
    import mgpusim
    loader = advisor._Loader(str(frame))
    opts = options(load_experiment(frame), max_gpus=3, links=LINKS)
    for option in opts[::7]:
        assert loader.load_as_given(option.overrides) == load_experiment(frame, option.overrides)
    twins = [loader.load_as_given(o.overrides) for o in opts if o.link == LINKS[0].name and o.gpus == 2][:2]
    assert twins[0].profile is twins[1].profile
    unused = {**opts[0].overrides, "profile.gpus.*.link.pcie_gen": 5}  # one GPU copies nothing
    row = evaluate(str(frame), {}, [(0, unused)], "full")[0]
    with pytest.raises(mgpusim.MgpusimError) as alone:
        mgpusim.simulate(load_experiment(frame, unused))
    assert row["error"] == str(alone.value)
