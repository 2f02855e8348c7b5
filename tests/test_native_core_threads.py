"""The native runner core's threads on host copies alone (no Vulkan call is made): parts copied
by the memcpy threads, a copy waiting for the one it depends on, and a stuck schedule stopped
with the nodes named."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from mgpusim.model.errors import InputError
from mgpusim.real.runner import native

needs_cc = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler to build the core")


def _run(deps: list[list[tuple[int, int]]], parts: list[list[tuple[np.ndarray, np.ndarray]]],
         threads: int = 3, stall_s: float = 5.0):
    """One host stream of len(deps) copies; copy i waits for deps[i] and copies parts[i]."""
    n = len(deps)
    table = np.zeros((n, len(native.COLUMNS)), dtype=np.int64)
    flat_deps, flat_parts, part_node = [], [], []
    for i in range(n):
        table[i, native.COL["kind"]] = native.KIND_HOST
        table[i, native.COL["dep_off"]], table[i, native.COL["dep_n"]] = len(flat_deps) // 2, len(deps[i])
        for p, edge in deps[i]:
            flat_deps += [p, edge]
        table[i, native.COL["part_off"]], table[i, native.COL["part_n"]] = len(part_node), len(parts[i])
        for dst, src in parts[i]:
            flat_parts += [dst.ctypes.data, src.ctypes.data, dst.nbytes]
            part_node.append(i)
    arrays = [np.array(a or [0, 0, 0], dtype=np.int64) for a in (flat_deps, flat_parts, part_node)]
    out = np.zeros((n, native.N_OUT), dtype=np.int64)
    part_out = np.zeros((max(1, len(part_node)), 3), dtype=np.int64)
    error = np.zeros(5, dtype=np.int64)
    streams = [np.arange(n, dtype=np.int64), np.array([0, n], dtype=np.int64),
               np.array([native.STREAM_HOST], dtype=np.int64)]
    sems = np.zeros(1, dtype=np.int64)
    rc = native._core().mgpusim_run(0, 0, 0, 0, table.ctypes.data, n, sems.ctypes.data,
                                    arrays[0].ctypes.data, arrays[1].ctypes.data, len(part_node),
                                    arrays[2].ctypes.data, *(a.ctypes.data for a in streams), 1,
                                    threads, int(stall_s * 1e9), out.ctypes.data,
                                    part_out.ctypes.data, error.ctypes.data)
    return rc, out, part_out, error


@needs_cc
def test_memcpy_threads_copy_every_part_in_dependency_order():
    rng = np.random.default_rng(1)
    src = [rng.integers(0, 255, 1 << 20, dtype=np.uint8) for _ in range(2)]
    dst = [np.zeros_like(s) for s in src]
    halves = [[(d[:k], s[:k]), (d[k:], s[k:])] for d, s, k in zip(dst, src, (1 << 19, 1 << 18))]
    rc, out, part_out, error = _run([[], [(0, native.EDGE_DONE)]], halves)
    assert rc == 0 and not error.any()
    assert all(np.array_equal(d, s) for d, s in zip(dst, src))
    assert (out[:, 0] <= out[:, 1]).all() and (out[:, 1] <= out[:, 2]).all()  # seen, call, called
    assert (part_out[:, 0] <= part_out[:, 1]).all() and set(part_out[:, 2]) <= {0, 1, 2}
    assert (part_out[:2, 0] >= out[0, 1]).all()  # a part starts once its copy queued it
    assert out[1, 0] >= part_out[:2, 1].max()  # copy 1 saw copy 0's last part end


@needs_cc
def test_a_stuck_schedule_stops_with_both_nodes_named():
    """Copy 0 waits for copy 1, which its own stream only reaches after copy 0: stuck."""
    buf = np.zeros(16, dtype=np.uint8)
    rc, _out, _parts, error = _run([[(1, native.EDGE_DONE)], []], [[(buf, buf.copy())], []],
                                   stall_s=0.2)
    assert rc == native.ERR_STUCK
    assert list(error[:3]) == [native.ERR_STUCK, 0, 1]


def test_runner_env_value_is_checked(monkeypatch):
    monkeypatch.setenv(native.RUNNER_ENV, "rust")
    with pytest.raises(InputError, match="MGPUSIM_RUNNER must be one of auto, python, native"):
        native.wanted()
    monkeypatch.setenv(native.RUNNER_ENV, "Native")
    assert native.wanted() == "native"
    monkeypatch.delenv(native.RUNNER_ENV)
    assert native.wanted() == "auto"
    assert native.wanted(" Python") == "python"  # a run's own argument before the variable
    with pytest.raises(InputError, match="runner must be one of auto, python, native, got 'rust'"):
        native.wanted("rust")
