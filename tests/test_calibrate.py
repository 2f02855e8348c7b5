"""Calibration: known coefficients are recovered; bad designs are flagged; output loads."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mgpusim import load_profile
from mgpusim.calibration import calibrate, fit_nonnegative
from mgpusim.calibration.profile_out import apply, lavapipe_base
from mgpusim.cli import main

ROOT = Path(__file__).resolve().parents[1]


def synthetic(rng: np.random.Generator, noise: float = 0.01) -> pd.DataFrame:
    rows = []
    for width, height in [(128, 64), (256, 192), (512, 384)]:
        for it in (10, 100, 1000):
            true = 5000 + 0.5 * width * height + 0.02 * width * height * it
            for rep in range(4):
                rows.append({"pass": "fragment_loop", "width": width, "height": height, "iterations": it,
                             "repetition": rep, "duration_ns": true * (1 + noise * rng.standard_normal())})
    for nbytes in (1 << 18, 1 << 22, 1 << 25):
        for queue in ("graphics", "transfer"):
            true = 3000 + nbytes / (8.0 if queue == "graphics" else 4.0)
            rows.append({"pass": "copy_d2h", "bytes": nbytes, "queue": queue, "repetition": 0, "duration_ns": true})
    for threads, tput in ((1, 5.0), (2, 9.0), (4, 12.0)):
        for nbytes in (1 << 22, 1 << 25):
            rows.append({"pass": "host_copy", "bytes": nbytes, "threads": threads, "repetition": 0,
                         "duration_ns": 1000 + nbytes / tput})
    df = pd.DataFrame(rows)
    df["source"] = "synthetic"
    return df


def test_recovers_known_coefficients_with_honest_uncertainty():
    cal = calibrate(synthetic(np.random.default_rng(1)), {})
    fit = cal.pass_fits["fragment_loop"]
    got = dict(zip(fit.names, fit.coef))
    err = dict(zip(fit.names, fit.stderr))
    assert got["ns_per_pixel_iteration"] == pytest.approx(0.02, rel=0.01)
    assert abs(got["ns_per_pixel_iteration"] - 0.02) < 4 * err["ns_per_pixel_iteration"] + 1e-12
    assert fit.rel_rms < 0.02 and not fit.warnings
    d2h = cal.copy_fits[("d2h", "graphics")]
    assert 1 / d2h.coef[1] == pytest.approx(8.0, rel=1e-6)
    assert d2h.coef[0] == pytest.approx(3000, rel=1e-3)
    assert cal.host["memcpy_thread_gbps"] == pytest.approx(5.0, rel=1e-3)
    assert cal.host["memory_bandwidth_gbps"] == pytest.approx(12.0, rel=1e-3)


def test_unidentifiable_and_ill_conditioned_fits_warn():
    x = np.linspace(1, 2, 10)
    fit = fit_nonnegative(np.column_stack([np.ones(10), x, 2 * x]), 3 + x, ["a", "b", "c"], "collinear")
    assert any("cannot tell" in w for w in fit.warnings)
    near = np.column_stack([np.ones(10), x, x + 1e-7 * np.arange(10)])
    fit = fit_nonnegative(near, 3 + x, ["a", "b", "c"], "near")
    assert any("ill-conditioned" in w or "cannot tell" in w for w in fit.warnings)


def test_calibrate_command_writes_a_loadable_lavapipe_profile(tmp_path, capsys):
    out = tmp_path / "lavapipe.toml"
    tables = sorted((ROOT / "data" / "lavapipe").glob("*.csv"))
    assert main(["calibrate", *map(str, tables), "--out", str(out)]) == 0
    profile = load_profile(out)
    assert profile.host.gpus_share_cpu and len(profile.gpus) == 4
    costs = profile.gpus[0].costs
    assert costs["fragment_loop"].ns_per["pixel_iteration"] > 0
    assert profile.gpus[0].queues["transfer"] == 0
    text = capsys.readouterr().out
    assert "+-" in text and "rms" in text  # coefficients with uncertainty, residuals
    assert (tmp_path / "lavapipe.fit.json").is_file()


def test_cores_per_pass_from_cpu_time_against_pass_time():
    """lavapipe tables with cpu_ns: CPU time = cores x pass time + a submission's overhead;
    the slope per kind (over the sizes' medians) is its cores, at least 1. Rows of another
    thread count (here 1) are another GPU's and enter neither fit; a table without cpu_ns
    fits no cores."""
    overhead = 500_000.0
    rows = []
    for kind, cores in (("fragment_loop", 1.9), ("mesh", 1.1), ("composite_sort_first", 0.5)):
        for width in (128, 256, 512):
            for threads in (1, 2):
                for rep, noise in enumerate((1.0, 1.02, 0.98)):
                    duration = 1e6 * width / 128 * (3 if threads == 1 else 1) * noise
                    used = cores if threads == 2 else 1.0
                    param = {"fragment_loop": "iterations", "mesh": "triangles"}.get(kind, "inputs")
                    rows.append({"pass": kind, "width": width, "height": 64, "lp_threads": threads,
                                 param: 100,
                                 "gpus": 1, "repetition": rep, "duration_ns": duration,
                                 "cpu_ns": used * duration + overhead})
    df = pd.DataFrame(rows)
    df["source"] = "t"
    cal = calibrate(df, {})
    assert cal.cores["fragment_loop"][0] == pytest.approx(1.9, rel=1e-3)
    assert cal.cores["mesh"][0] == pytest.approx(1.1, rel=1e-3)
    assert cal.cores["composite_sort_first"][0] == 1.0  # the queue thread's core at least
    assert cal.submission_cpu_ns["mesh"] == pytest.approx(overhead, rel=1e-3)
    assert all(r == pytest.approx(1.9, rel=1e-3) for r in cal.cores["fragment_loop"][1])
    # the cost fit saw the 2-thread rows only: 1 ms at width 128
    fit = cal.pass_fits["fragment_loop"]
    predicted = fit.coef @ np.array([1.0, 128 * 64, 128 * 64 * 100])
    assert predicted == pytest.approx(1e6, rel=0.05)
    assert not calibrate(df.drop(columns="cpu_ns"), {}).cores


def _mesh_rows(shape: str, cull: str, slowdown) -> list[dict]:
    """Mesh rows alone and two at once, their times from fixed coefficients, the pairs'
    slowdown given by `slowdown(queue-thread ns, total ns)`."""
    from mgpusim.calibration.pass_fit import pass_work
    coef = {"triangle": 15.0, "visible_triangle": 75.0, "triangle_edge": 25.0, "fragment": 3.0}
    rows = []
    for width, height in ((128, 96), (320, 240)):
        for triangles in (2000, 10000, 40000):
            key = {"pass": "mesh", "width": width, "height": height, "triangles": triangles,
                   "place": "whole", "shape": shape, "cull": cull, "lp_threads": 4}
            work = pass_work(pd.Series(key))
            thread = coef["triangle"] * work["triangle"]
            alone = 2e5 + sum(coef.get(t, 0.0) * a for t, a in work.items())
            for gpus in (1, 2):
                duration = alone * (slowdown(thread, alone) if gpus == 2 else 1.0)
                for gpu in range(gpus):
                    rows.append({**key, "gpus": gpus, "gpu": f"gpu{gpu}", "repetition": 0,
                                 "duration_ns": duration, "cpu_ns": 1.2 * duration})
    return rows


def test_a_meshs_queue_thread_cores_are_told_apart_where_pairs_mix_them():
    """Pairs of torus draws (every triangle rasterized) and of culled sphere draws (81 % of the
    triangles culled on the queue thread) whose slowdowns follow 1 core for the triangles'
    queue-thread work and 1.9 for the rest: the fit finds both and writes them; with the torus
    alone (one mix) the mesh keeps one `cores`."""
    def slowdown(thread, total):
        return (1.0 * thread + 1.9 * (total - thread)) / total
    df = pd.DataFrame(_mesh_rows("torus", "none", slowdown) + _mesh_rows("sphere", "back", slowdown))
    df["source"] = "t"
    cal = calibrate(df, {})
    assert cal.term_cores["mesh"]["triangle"] == pytest.approx(1.0, abs=0.02)
    assert cal.cores["mesh"][0] == pytest.approx(1.9, abs=0.02)
    written = apply(cal, lavapipe_base({"cpu_count": 2}), "test")["gpus"][0]["costs"]["mesh"]
    assert written["term_cores"] == {"triangle": pytest.approx(1.0, abs=0.02)}
    load = parse_profile_dict(apply(cal, lavapipe_base({"cpu_count": 2}), "test"))
    assert load.gpus[0].costs["mesh"].term_cores["triangle"] == pytest.approx(1.0, abs=0.02)
    torus = pd.DataFrame(_mesh_rows("torus", "none", slowdown))
    torus["source"] = "t"
    alone = calibrate(torus, {})
    assert "mesh" not in alone.term_cores and 1.0 < alone.cores["mesh"][0] < 1.9


def parse_profile_dict(data: dict):
    from mgpusim.model.profile import parse_profile
    return parse_profile(data, "test")


def test_cores_of_a_kind_measured_in_pairs_are_its_slowdown_two_at_once():
    """Where a table has a kind on two GPUs at once as well as alone (pair sweeps), its cores
    are the median over sizes of time together / time alone, whatever its CPU time says; the
    pair rows enter no cost fit, and a kind without pairs keeps the CPU-time slope."""
    rows = []
    slowdown = {128: 1.3, 256: 1.45, 512: 1.5}
    for kind, cpu_cores in (("mesh", 1.15), ("fragment_loop", 1.9)):
        for width in (128, 256, 512):
            for gpus in (1, 2):
                if gpus == 2 and kind != "mesh":
                    continue
                for rep, noise in enumerate((1.0, 1.01, 0.99)):
                    alone = 1e6 * width / 128 * noise
                    duration = alone * (slowdown[width] if gpus == 2 else 1.0)
                    for gpu in range(gpus):
                        rows.append({"pass": kind, "width": width, "height": 64, "lp_threads": 4,
                                     "triangles" if kind == "mesh" else "iterations": 100,
                                     "gpus": gpus, "gpu": f"gpu{gpu}", "repetition": rep,
                                     "duration_ns": duration, "cpu_ns": cpu_cores * duration + 1e5})
    df = pd.DataFrame(rows)
    df["source"] = "t"
    cal = calibrate(df, {})
    assert cal.cores["mesh"][0] == pytest.approx(1.45, rel=1e-3)
    assert sorted(cal.cores["mesh"][1]) == pytest.approx([1.3, 1.45, 1.5], rel=1e-3)
    assert cal.cores_method == {"mesh": "slowdown of two at once"}
    written = apply(cal, lavapipe_base({"cpu_count": 2}), "test")["gpus"][0]["costs"]
    assert written["mesh"]["cores_from_pairs"] and "cores_from_pairs" not in written["fragment_loop"]
    assert cal.cores["fragment_loop"][0] == pytest.approx(1.9, rel=1e-3)
    # the cost fit saw the rows alone (with the pair rows, 1.3-1.5x slower, it could not fit)
    assert cal.pass_fits["mesh"].rel_rms < 0.02


def test_filter_pass_is_fitted_with_its_inputs():
    """The filter (temporal pass, pipelining chain) gets ns per pixel, per pixel iteration and
    per pixel and input, as the schedules' work terms count them."""
    rows = []
    for width, height in [(64, 48), (128, 96), (256, 192)]:
        for it in (10, 1000):
            for inputs in (1, 2, 4):
                px = width * height
                rows.append({"pass": "filter", "width": width, "height": height, "iterations": it,
                             "inputs": inputs, "repetition": 0,
                             "duration_ns": 2000 + 0.3 * px + 0.01 * px * it + 0.2 * px * inputs})
    df = pd.DataFrame(rows)
    df["source"] = "synthetic"
    from mgpusim.calibration.measure_tables import check_measure_table
    check_measure_table(df, "filter.csv")  # a known pass of the measure library
    fit = calibrate(df, {}).pass_fits["filter"]
    got = dict(zip(fit.names, fit.coef))
    assert got["ns_per_pixel_input"] == pytest.approx(0.2, rel=1e-6)
    assert got["ns_per_pixel_iteration"] == pytest.approx(0.01, rel=1e-6)
    assert got["ns_per_pixel"] == pytest.approx(0.3, rel=1e-6)


def _particle_rows(sizes, counts) -> pd.DataFrame:
    rows = [{"pass": "particle_render", "width": w, "height": h, "particles": n, "repetition": 0,
             "duration_ns": 3000 + 2.0 * n + 0.1 * w * h + 1e-5 * n * w * h}
            for w, h in sizes for n in counts]
    df = pd.DataFrame(rows)
    df["source"] = "synthetic"
    return df


def test_particle_draws_are_priced_per_particle_and_pixel_where_the_table_sweeps_both():
    fit = calibrate(_particle_rows([(640, 360), (1280, 720), (2560, 1440)], (1e4, 1e5, 1e6)), {}
                    ).pass_fits["particle_render"]
    got = dict(zip(fit.names, fit.coef))
    assert got["ns_per_particle_pixel"] == pytest.approx(1e-5, rel=1e-6)
    assert got["ns_per_particle"] == pytest.approx(2.0, rel=1e-6)


def test_a_table_of_one_view_size_keeps_the_older_particle_draw_model():
    """One view size cannot tell particles x pixels from particles: the optional term is left
    out, with a warning, rather than splitting the time between them arbitrarily."""
    cal = calibrate(_particle_rows([(1280, 720)], (1e4, 1e5, 1e6)), {})
    fit = cal.pass_fits["particle_render"]
    assert "ns_per_particle_pixel" not in fit.names
    assert any("particle_pixel" in w and "left out" in w for w in cal.warnings)


def test_a_fit_that_does_not_converge_is_an_input_error(monkeypatch):
    """scipy's solver raises RuntimeError at its iteration limit: calibrate says so in one line
    naming the fit instead of crashing."""
    from mgpusim.calibration import fit as fit_module
    from mgpusim.model.errors import InputError

    def no_convergence(*args, **kwargs):
        raise RuntimeError("Maximum number of iterations reached.")
    monkeypatch.setattr("scipy.optimize.nnls", no_convergence)  # imported where it fits
    X = np.array([[1.0, 1.0], [1.0, 2.0], [1.0, 3.0]])
    with pytest.raises(InputError, match="mesh: .*did not converge"):
        fit_module.fit_nonnegative(X, np.array([2.0, 3.0, 4.0]), ["fixed_ns", "ns_per_pixel"], "mesh")


def test_a_mesh_table_of_one_view_size_keeps_its_placed_terms():
    """Only the particle draw's optional term falls back to the older model; a mesh table of one
    view size keeps the placed terms (and says where it cannot tell them apart)."""
    from mgpusim.calibration.pass_fit import read_measurements
    df, _ = read_measurements([ROOT / "data" / "nvidia" / "h200_x4" / "measurements" / "mesh_1080.csv"])
    fit = calibrate(df, {}).pass_fits["mesh"]
    assert {"ns_per_fragment", "ns_per_triangle_edge", "ns_per_visible_triangle"} <= set(fit.names)


def test_host_copies_without_a_resolved_per_byte_cost_give_a_finite_rate():
    """Noise can swamp the bytes of a thread count's copies (a flat duration): the rate is then
    the fastest whole copy, finite and loadable, with a warning, never infinite."""
    df = synthetic(np.random.default_rng(1))
    flat = (df["pass"] == "host_copy") & (df["threads"] == 4)
    df.loc[flat, "duration_ns"] = [4.0e6, 3.9e6]
    cal = calibrate(df, {})
    assert cal.host["memory_bandwidth_gbps"] == pytest.approx((1 << 25) / 3.9e6, rel=1e-6)
    assert any("host_copy x4" in w and "lower bound" in w for w in cal.warnings)
    apply(cal, lavapipe_base({}, gpus=2), "test")  # loads: no infinite bandwidth


@pytest.mark.parametrize("seed", range(12))
def test_any_noisy_or_flat_measurement_gives_a_profile_that_loads(seed):
    """The committed lavapipe tables with every duration off by up to 3x either way, and three
    pass kinds' durations made flat (the bytes or sizes making no difference, as noise can on a
    busy machine): the calibrated profile always loads. An unresolved copy rate is the fastest
    whole copy, never 1 / (a slope of 1e-19)."""
    from mgpusim.calibration.pass_fit import read_measurements
    df, machine = read_measurements(sorted((ROOT / "data" / "lavapipe").glob("*.csv")))
    rng = np.random.default_rng(seed)
    df["duration_ns"] *= np.exp(rng.uniform(np.log(1 / 3), np.log(3), len(df)))
    for kind in rng.choice(df["pass"].unique(), size=3, replace=False):
        flat = df["pass"] == kind
        df.loc[flat, "duration_ns"] = float(df.loc[flat, "duration_ns"].median())
    profile = apply(calibrate(df, machine), lavapipe_base(machine, gpus=2), "test")
    assert 0 < profile["host"]["memory_bandwidth_gbps"] < 1e4
