"""`mgpusim devices` and `mgpusim measure` end to end, and the one-line errors."""
from __future__ import annotations

import json

import pandas as pd
import pytest

from mgpusim.cli import main
from mgpusim.model.errors import DependencyError
from mgpusim.real.vulkan import shader_cache
from mgpusim.real.vulkan import vk_errors as vkerrors

pytestmark = pytest.mark.vulkan


def test_devices_lists_lavapipe(capsys):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    assert "llvmpipe" in out and "queue family 0" in out and "VK_EXT_external_memory_host" in out


def test_measure_list(capsys):
    assert main(["measure", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("fragment_loop", "mesh", "composite_sort_first", "composite_sort_last",
                 "filter", "particle_update", "particle_render", "copy_d2h", "copy_h2d", "copy_d2d",
                 "host_copy"):
        assert name in out


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_measure_writes_tidy_table_and_machine_record(tmp_path, ext):
    out = tmp_path / f"t.{ext}"
    rc = main(["measure", "--pass", "fragment_loop", "--sweep", "iterations=10,100",
               "--sweep", "width=32", "--sweep", "height=16", "--reps", "3", "--warmup", "1",
               "--gpus", "2", "--quiet", "--out", str(out)])
    assert rc == 0
    df = pd.read_csv(out) if ext == "csv" else pd.read_parquet(out)
    assert list(df.columns) == ["device", "gpu", "gpus", "lp_threads", "pass", "width", "height",
                                "iterations", "repetition", "duration_ns", "cpu_ns", "bytes"]
    assert (df.lp_threads >= 1).all()  # lavapipe: the rasterizer threads of each row
    assert df.cpu_ns.isna().all()  # two GPUs at once: CPU time is not one pass's
    assert len(df) == 2 * 2 * 3 and set(df.repetition) == {0, 1, 2}
    assert (df.duration_ns > 0).all() and (df.bytes == 32 * 16 * 4).all()
    record = json.loads((tmp_path / f"t.{ext}.machine.json").read_text())
    assert record["cpu"] and len(record["gpus"]) == 2 and record["libraries"]["vulkan"]


def test_measure_records_the_cpu_time_of_each_pass_alone(tmp_path):
    out = tmp_path / "m.csv"
    assert main(["measure", "--pass", "fragment_loop", "--sweep", "iterations=2000",
                 "--sweep", "width=128", "--sweep", "height=96", "--reps", "3", "--quiet",
                 "--out", str(out)]) == 0
    df = pd.read_csv(out)
    # the pass's rasterizer threads: at least most of one core for the pass's duration
    assert (df.cpu_ns > 0.5 * df.duration_ns).all()


def test_measure_copy_and_host_copy(tmp_path):
    out = tmp_path / "c.csv"
    assert main(["measure", "--pass", "copy_d2h", "--sweep", "bytes=64KiB,256KiB", "--reps", "2",
                 "--warmup", "1", "--quiet", "--out", str(out)]) == 0
    assert sorted(pd.read_csv(out).bytes.unique()) == [65536, 262144]
    assert main(["measure", "--pass", "host_copy", "--sweep", "threads=1,2", "--reps", "2",
                 "--quiet", "--out", str(out)]) == 0
    assert set(pd.read_csv(out).device) == {"host"}


@pytest.mark.parametrize("argv, needle", [
    (["--pass", "nope"], "unknown pass"),
    (["--pass", "mesh", "--sweep", "foo=1"], "no parameter 'foo'"),
    (["--pass", "mesh", "--sweep", "triangles=lots"], "expected an integer"),
    (["--pass", "mesh", "--sweep", "triangles=10"], "need --pass NAME and --out"),
])
def test_measure_bad_input_is_one_line(capsys, tmp_path, argv, needle):
    if "triangles=10" not in argv:
        argv = argv + ["--out", str(tmp_path / "x.csv")]
    assert main(["measure", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err


def test_missing_compiler_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setattr(vkerrors.shutil, "which", lambda name: None)
    monkeypatch.setenv("MGPUSIM_CACHE", str(tmp_path))
    shader_cache.spirv.cache_clear()
    try:
        with pytest.raises(DependencyError, match="apt-get install glslc"):
            shader_cache.spirv("loop.frag")
    finally:
        shader_cache.spirv.cache_clear()


def test_shader_cache_reuses_binaries(monkeypatch, tmp_path):
    monkeypatch.setenv("MGPUSIM_CACHE", str(tmp_path))
    shader_cache.spirv.cache_clear()
    try:
        code = shader_cache.spirv("quad.vert")
        files = list((tmp_path / "spirv").glob("quad-vert-*.spv"))
        assert len(files) == 1 and files[0].read_bytes() == code
        assert code[:4] == b"\x03\x02\x23\x07"  # SPIR-V magic, little-endian
    finally:
        shader_cache.spirv.cache_clear()


def test_measure_filter_sweeps_its_inputs(tmp_path):
    """The temporal pass / pipelining chain's filter is measured like the other passes: its
    inputs are a column the calibration fits (`pixel_input`)."""
    out = tmp_path / "f.csv"
    assert main(["measure", "--pass", "filter", "--sweep", "inputs=1,4", "--sweep", "width=64",
                 "--sweep", "height=48", "--sweep", "iterations=100", "--reps", "2",
                 "--warmup", "1", "--quiet", "--out", str(out)]) == 0
    df = pd.read_csv(out)
    assert sorted(set(df.inputs)) == [1, 4] and (df.duration_ns > 0).all()
    assert (df.bytes == 64 * 48 * 4).all()
