"""Bad input through every command ends in one line on stderr, exit code 2, no traceback, and
nothing written to --out.

Each case builds its files in a fresh folder, runs the CLI in-process (mgpusim.cli.main) and
checks the line names what was wrong (a file, an option or a field, and the words that say
why). Files: experiments, hardware profiles, measured-run folders (`validate --measured`), measure
tables (`calibrate`) and study files; commands: simulate, validate, calibrate, study, run and
measure (only their checks that come before any Vulkan device is opened).
"""
from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pandas as pd
import pytest
import tomli_w

from mgpusim import InputError, load_experiment, simulate
from mgpusim.cli import main
from mgpusim.model.costs import CostModel
from mgpusim.model.profile import parse_profile
from mgpusim.model.tasks import Dep, PassTask, QueueRef
from mgpusim.schedules.base import FrameProgram
from mgpusim.sim.engine import Engine
from tests.conftest import profile_dict

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = {
    "sf": "sort_first_tc1.toml", "sl": "sort_last_tc1.toml", "afr": "afr_temporal_tc1.toml",
    "pipe": "pipelining_miniengine_pcie3x8.toml", "xr": "xr_quest3_pcie4.toml",
    "part": "particles_machine.toml",
}


def experiment(key: str = "sf") -> dict[str, Any]:
    """A shipped experiment as a dict, its profile path made absolute."""
    path = ROOT / "experiments" / EXPERIMENTS[key]
    data = tomllib.loads(path.read_text())
    data["profile"] = str((path.parent / data["profile"]).resolve())
    return data


def tc1() -> dict[str, Any]:
    return tomllib.loads((ROOT / "hardware_profiles" / "tc1.toml").read_text())


def write_toml(path: Path, data: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(data))
    return path


@dataclass
class Case:
    id: str
    #: (tmp folder) -> argv; --out (if any) must be tmp / "out"
    make: Callable[[Path], list[str]]
    #: words the one line must contain
    expect: tuple[str, ...]


CASES: list[Case] = []


def case(name: str, *expect: str) -> Callable[[Callable[[Path], list[str]]], Callable]:
    def wrap(make: Callable[[Path], list[str]]) -> Callable:
        CASES.append(Case(name, make, expect))
        return make
    return wrap


def simulate_argv(exp: Path, tmp: Path, *sets: str) -> list[str]:
    return ["simulate", str(exp), "--out", str(tmp / "out"), *[a for s in sets for a in ("--set", s)]]


# ----- --set overrides on simulate --------------------------------------------------------
SET_CASES = [
    ("sf", "=3", "no key"),
    ("sf", "schedule.gpus", "key=value"),
    ("sf", ".gpus=3", "empty part"),
    ("sf", "schedule..gpus=3", "empty part"),
    ("sf", "scene.passes.5.iterations=1", "not an index below 1"),
    ("sf", "scene.passes.x.iterations=1", "not an index"),
    ("sf", "scene.passes.-1.iterations=1", "not an index"),
    ("sf", "scene.width.x=3", "scene.width is not a table"),
    ("sf", "schedule.gpus=nan", "schedule.gpus"),
    ("sf", "schedule.gpus=inf", "schedule.gpus"),
    ("sf", "schedule.gpus=4", "profile.gpu_count=4"),
    ("sf", "schedule.gpus=1000", "<= 64"),
    ("sf", "schedule.frames=100000000", "<= 1e+07"),
    ("sf", "schedule.frames=10000001", "<= 1e+07"),
    ("sf", "schedule.frames=0", ">= 1"),
    ("sf", "scene.width=nan", "scene.width"),
    ("sf", "scene.width=1e400", "scene.width"),
    ("sf", "scene.passes.0.iterations=nan", "finite"),
    ("sf", "scene.passes.0.iterations=inf", "finite"),
    ("sf", "scene.passes.0.iterations=-inf", "finite"),
    ("sf", "scene.passes.0.iteratons=1", "did you mean 'iterations'"),
    ("sf", "schedule.hostcopy=false", "did you mean 'host_copy'"),
    ("sf", "profile=5", "expected a string"),
    ("sf", "profile.gpus.0.link.pcie_gen=9", "gpus[0].link.pcie_gen"),
    ("sf", "profile.gpus.0.link.lanes=3", "gpus[0].link.lanes"),
    ("sf", "profile.gpus.9.speed=2", "not an index below 2"),
    ("sf", "profile.gpus.*.speed=-1", "gpus[0].speed"),
    ("sf", "profile.gpus.0.speed=nan", "finite"),
    ("sf", "profile.host.memcpy_threads=100000", "<= 1024"),
    ("sf", "profile.host.memcpy_thread=2", "did you mean 'memcpy_threads'"),
    ("sf", "profile.gpu_count=0", "gpu_count"),
    ("sf", "profile.gpu_count=65", "<= 64"),
    ("sf", "profile.peer_mesh.bandwidth_gbps=0", "peer_mesh"),
    ("sf", "profile.peer_mesh.bandwidth_gbps=300", "peer_mesh.latency_ns"),
    ("sf", "profile.nope=1", "unknown key"),
    ("sf", "profile.name=3", "expected a string"),
    ("sf", "profile.gpus.0.costs.fragment_loop.ns_per_pixle=1", "did you mean 'ns_per_pixel'"),
    ("sf", "a.b.c.d.e.f.g.h.i.j.k.l.m.n.o.p.q.r=1", "dotted parts"),
    ("sf", "profile.gpus.0.link.h2d_gbps=1e-9", "gpus[0].link.h2d_gbps"),
    ("pipe", "schedule.chunks=1000000", "<= 1024"),
    ("pipe", "schedule.split_at=100", "schedule.split_at"),
    ("pipe", "schedule.copy_granularity=frme", "did you mean 'frame'"),
    ("pipe", "schedule.path=peer", "peer link"),
]
for _i, (_key, _set, _words) in enumerate(SET_CASES):
    def _make(tmp: Path, key=_key, s=_set) -> list[str]:
        return simulate_argv(write_toml(tmp / "e.toml", experiment(key)), tmp, s)
    CASES.append(Case(f"set-{_i}-{_set}", _make, ("error", _words)))


# ----- experiment files ------------------------------------------------------------------
def _put(path: str, value: Any) -> Callable[[dict], None]:
    """A mutation setting a dotted path (numbers index lists) to `value`."""
    def mutate(data: dict) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        node[int(last) if isinstance(node, list) else last] = value
    return mutate


def _drop(path: str) -> Callable[[dict], None]:
    def mutate(data: dict) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        del node[last]
    return mutate


EXPERIMENT_CASES: list[tuple[str, Callable[[dict], None], tuple[str, ...]]] = [
    ("sf", _put("name", 5), ("name", "string")),
    ("sf", _put("description", []), ("description",)),
    ("sf", _drop("profile"), ("profile", "missing")),
    ("sf", _put("profile", "nonexistent.toml"), ("profile", "not found")),
    ("sf", _put("profile", "/"), ("profile", "not found")),
    ("sf", _drop("scene"), ("scene", "missing")),
    ("sf", _put("scene", 3), ("scene", "table")),
    ("sf", _put("scene.width", 0), ("scene.width", ">= 1")),
    ("sf", _put("scene.width", -1), ("scene.width",)),
    ("sf", _put("scene.width", 1000.0), ("scene.width", "integer")),
    ("sf", _put("scene.width", 10**6), ("scene.width", "<= 65536")),
    ("sf", _put("scene.width", 10**30), ("scene.width", "<= 65536")),
    ("sf", _put("scene.width", "wide"), ("scene.width", "integer")),
    ("sf", _put("scene.width", True), ("scene.width", "integer")),
    ("sf", _put("scene.height", 70000), ("scene.height", "<= 65536")),
    ("sf", _put("scene.color_bytes_per_pixel", 0), ("color_bytes_per_pixel",)),
    ("sf", _put("scene.color_bytes_per_pixel", 1000), ("color_bytes_per_pixel", "<= 64")),
    ("sf", _put("scene.depth_bytes_per_pixel", -1), ("depth_bytes_per_pixel",)),
    ("sf", _put("scene.dataset_bytes", 2**60), ("dataset_bytes", "1 PiB")),
    ("sf", _put("scene.dataset_bytes", 1e20), ("dataset_bytes", "integer")),
    ("sf", _put("scene.dataset_bytes", 2**40), ("scene.dataset_bytes", "overflows")),
    ("sf", lambda d: d["scene"].update(width=65536, height=65536), ("scene.width x scene.height", "overflows")),
    ("sf", _put("scene.widht", 5), ("did you mean 'width'",)),
    ("sf", _put("scene.passes", []), ("scene.passes", "empty")),
    ("sf", _drop("scene.passes"), ("scene.passes", "missing")),
    ("sf", _put("scene.passes", "x"), ("scene.passes",)),
    ("sf", _put("scene.passes.0", 5), ("scene.passes[0]", "table")),
    ("sf", _put("scene.passes.0.kind", "fragment_lop"), ("did you mean 'fragment_loop'",)),
    ("sf", _drop("scene.passes.0.kind"), ("scene.passes[0].kind", "missing")),
    ("sf", _drop("scene.passes.0.name"), ("scene.passes[0].name", "missing")),
    ("sf", lambda d: d["scene"]["passes"].append(dict(d["scene"]["passes"][0])), ("duplicate pass name",)),
    ("sf", _put("scene.passes.0.iterations", float("nan")), ("iterations", "finite")),
    ("sf", _put("scene.passes.0.iterations", float("inf")), ("iterations", "finite")),
    ("sf", _put("scene.passes.0.iterations", -1), ("iterations", ">= 0")),
    ("sf", _put("scene.passes.0.iterations", "many"), ("iterations", "number")),
    ("sf", _put("scene.passes.0.iterations", 1e16), ("iterations", "<= 1e+15")),
    ("sf", _put("scene.passes.0.iterations", True), ("iterations", "number")),
    ("sf", _put("scene.passes.0.iterations", 10**400), ("iterations", "finite")),
    ("sf", _put("scene.passes.0.iteratons", 5), ("did you mean 'iterations'",)),
    ("sf", _put("scene.passes.0.iterations", 1e14), ("fragment_loop pass would take", "1e+12 ns")),
    ("sl", _put("scene.passes.0.triangels", 5), ("did you mean 'triangles'",)),
    ("sl", _put("scene.passes.0.triangles", float("nan")), ("triangles", "finite")),
    ("sf", _drop("schedule"), ("schedule", "missing")),
    ("sf", _drop("schedule.name"), ("schedule.name", "missing")),
    ("sf", _put("schedule.name", "sort_frist"), ("did you mean 'sort_first'",)),
    ("sf", _put("schedule.name", 5), ("schedule.name", "string")),
    ("sf", _put("schedule.gpus", 0), ("schedule.gpus", ">= 1")),
    ("sf", _put("schedule.gpus", "two"), ("schedule.gpus", "integer")),
    ("sf", _put("schedule.frames", 2.5), ("schedule.frames", "integer")),
    ("sf", _put("schedule.frames", 10**8), ("schedule.frames", "<= 1e+07")),
    ("sf", _put("schedule.warmup_frames", 60), ("warmup_frames", "< frames")),
    ("sf", _put("schedule.warmup_frames", -1), ("warmup_frames", ">= 0")),
    ("sf", _put("schedule.frames_in_flight", 0), ("frames_in_flight", ">= 1")),
    ("sf", _put("schedule.frames_in_flight", 100), ("frames_in_flight", "<= 64")),
    ("sf", _put("schedule.buffers", 0), ("schedule.buffers", ">= 1")),
    ("sf", _put("schedule.buffers", 1000), ("schedule.buffers", "<= 64")),
    ("sf", _put("schedule.host_copy", "yes"), ("schedule.host_copy", "true or false")),
    ("sf", _put("schedule.tile_rows", [1, 2]), ("schedule.tile_rows", "summing")),
    ("sf", _put("schedule.tile_rows", ["a", "b"]), ("schedule.tile_rows",)),
    ("sf", _put("schedule.tile_rows", [384, 385]), ("schedule.tile_rows", "768")),
    ("sf", _put("schedule.gpu", 2), ("schedule.gpu", "did you mean 'gpus'")),
    ("sf", _put("schedul", {}), ("did you mean 'schedule'",)),
    ("afr", _put("schedule.temporal_pass", "tta"), ("schedule.temporal_pass", "no scene pass")),
    ("afr", _put("schedule.history_bytes", -1), ("history_bytes", ">= 0")),
    ("afr", _put("schedule.present_queue", "x"), ("present_queue", "one of")),
    ("afr", _put("schedule.path", "perr"), ("schedule.path", "did you mean 'peer'")),
    ("afr", _put("schedule.path", "peer"), ("no peer link",)),
    ("pipe", _put("schedule.split_at", 100), ("schedule.split_at", "passes")),
    ("pipe", _put("schedule.chunks", 0), ("schedule.chunks", ">= 1")),
    ("pipe", _put("scene.passes.0.output_bytes", -5), ("output_bytes", ">= 0")),
    ("pipe", _put("scene.passes.0.duration_ms", 1e9), ("timed pass would take",)),
    ("pipe", _put("scene.passes.0.output_bytes", 1e15), ("receive buffers", "overflows")),
    ("part", _put("schedule.particle_gpu", 5), ("schedule.particle_gpu", "GPU")),
    ("part", _put("schedule.particle_gpu", 100), ("schedule.particle_gpu", "<= 63")),
    ("part", _put("schedule.draw_after", "geometri"), ("schedule.draw_after",)),
    ("part", _put("schedule.particles", -1), ("schedule.particles", ">= 0")),
    ("part", _put("schedule.particles", 10**13), ("schedule.particles", "<= 1e+12")),
    ("part", _put("schedule.policy", "waitt"), ("schedule.policy", "did you mean 'wait'")),
    ("part", _put("schedule.vertex_bytes_per_particle", 10**6), ("vertex_bytes_per_particle",)),
    ("xr", _put("schedule.views", 3), ("schedule.views", "one of")),
    ("xr", _put("schedule.mode", "x"), ("schedule.mode",)),
    ("xr", _put("schedule.handoff_us", float("nan")), ("handoff_us", "finite")),
    ("xr", _put("schedule.handoff_us", 1e10), ("handoff_us", "<= 1e+09")),
    ("xr", _put("schedule.scaling", "medium"), ("schedule.scaling",)),
    ("xr", _put("schedule.buffers", 0), ("schedule.buffers",)),
    ("xr", _put("schedule.frames_in_flight", 9), ("frames in flight",)),
]
for _i, (_key, _mutate, _words) in enumerate(EXPERIMENT_CASES):
    def _make(tmp: Path, key=_key, mutate=_mutate) -> list[str]:
        data = experiment(key)
        mutate(data)
        return simulate_argv(write_toml(tmp / "e.toml", data), tmp)
    CASES.append(Case(f"experiment-{_key}-{_i}", _make, ("e.toml", *_words)))


# ----- hardware profiles -----------------------------------------------------------------
PROFILE_CASES: list[tuple[Callable[[dict], None], tuple[str, ...]]] = [
    (_put("host.memory_bandwidth_gbps", float("nan")), ("host.memory_bandwidth_gbps", "finite")),
    (_put("host.memory_bandwidth_gbps", float("inf")), ("host.memory_bandwidth_gbps", "finite")),
    (_put("host.memory_bandwidth_gbps", -1.0), ("host.memory_bandwidth_gbps", "> 0")),
    (_put("host.memory_bandwidth_gbps", 0), ("host.memory_bandwidth_gbps", "> 0")),
    (_put("host.memory_bandwidth_gbps", "fast"), ("host.memory_bandwidth_gbps", "number")),
    (_put("host.memory_bandwidth_gbps", 1e13), ("host.memory_bandwidth_gbps", "<= 1e+12")),
    (_put("host.memcpy_threads", 0), ("host.memcpy_threads", ">= 1")),
    (_put("host.memcpy_threads", 10**9), ("host.memcpy_threads", "<= 1024")),
    (_put("host.memcpy_threads", 2.5), ("host.memcpy_threads", "integer")),
    (_put("host.memcpy_threads", True), ("host.memcpy_threads", "integer")),
    (_put("host.cpu_cores", 10**6), ("host.cpu_cores", "<= 1024")),
    (_put("host.host_copy_fixed_ns", 10**13), ("host.host_copy_fixed_ns", "int64")),
    (_put("host.host_copy_fixed_ns", -1), ("host.host_copy_fixed_ns", ">= 0")),
    (_put("host.dispatch_ns", 1e30), ("host.dispatch_ns", "integer")),
    (_put("host.submit_ns", 10**20), ("host.submit_ns", "<= 1e+12")),
    (_put("host.oversubscribed_efficiency", 1.5), ("oversubscribed_efficiency", "<= 1")),
    (_put("host.oversubscribed_efficiency", float("nan")), ("oversubscribed_efficiency", "finite")),
    (_put("host.memory_bandwith_gbps", 3.0), ("did you mean 'memory_bandwidth_gbps'",)),
    (_put("host.memcpy_thread", 1), ("did you mean 'memcpy_threads'",)),
    (_drop("host"), ("host", "missing")),
    (_put("hosts", {}), ("did you mean 'host'",)),
    (_drop("name"), ("name", "missing")),
    (_put("name", 5), ("name", "string")),
    (_put("gpus", []), ("gpus", "empty")),
    (_drop("gpus"), ("gpus", "missing")),
    (_put("gpus", "x"), ("gpus",)),
    (_put("gpus.0.count", 0), ("gpus[0].count", ">= 1")),
    (_put("gpus.0.count", 10**6), ("gpus[0].count", "<= 64")),
    (_put("gpus.0.count", 64), ("gpus[1].count", "65 GPUs")),
    (_put("gpus.0.memory_bytes", 0), ("gpus[0].memory_bytes", ">= 1")),
    (_put("gpus.0.memory_bytes", 2**60), ("gpus[0].memory_bytes", "1 PiB")),
    (_put("gpus.0.queues.graphics", 0), ("gpus[0].queues.graphics", "at least one")),
    (_put("gpus.0.queues.graphics", 10**6), ("gpus[0].queues.graphics", "<= 64")),
    (_put("gpus.0.queues.copy", 1), ("gpus[0].queues.copy", "unknown key")),
    (_put("gpus.0.link.pcie_gen", 7), ("gpus[0].link.pcie_gen", "one of")),
    (_put("gpus.0.link.lanes", 3), ("gpus[0].link.lanes", "one of")),
    (_put("gpus.0.link.efficiency", 1.5), ("gpus[0].link.efficiency", "<= 1")),
    (_put("gpus.0.link.efficiency", float("nan")), ("gpus[0].link.efficiency", "finite")),
    (_put("gpus.0.link.latency_ns", -5), ("gpus[0].link.latency_ns", ">= 0")),
    (_put("gpus.0.link.latency_ns", 10**13), ("gpus[0].link.latency_ns", "<= 1e+12")),
    (_put("gpus.0.link.h2d_gbps", 0), ("gpus[0].link.h2d_gbps", "> 0")),
    (_put("gpus.0.link.h2d_gbps", float("inf")), ("gpus[0].link.h2d_gbps", "finite")),
    (_put("gpus.0.link.h2d_gbps", 1e-9), ("copy", "gpus[0].link.h2d_gbps", "1e+12 ns")),
    (_put("gpus.0.link.d2h_gbps", 1e-9), ("copy", "gpus[1].link.d2h_gbps", "1e+12 ns")),
    (_put("gpus.0.link.pcie_gn", 3), ("did you mean 'pcie_gen'",)),
    (_put("gpus.0.costs.fragment_loop.ns_per_pixle", 0.1), ("did you mean 'ns_per_pixel'",)),
    (_put("gpus.0.costs.fragmnt_loop", {}), ("did you mean 'fragment_loop'",)),
    (_put("gpus.0.costs.mesh.ns_per_triangle", float("nan")), ("ns_per_triangle", "finite")),
    (_put("gpus.0.costs.mesh.ns_per_triangle", -1.0), ("ns_per_triangle", ">= 0")),
    (_put("gpus.0.costs.mesh.ns_per_triangle", 1e13), ("ns_per_triangle", "<= 1e+12")),
    (_put("gpus.0.costs.mesh.fixed_ns", 1e13), ("costs.mesh.fixed_ns", "<= 1e+12")),
    (_put("gpus.0.costs.mesh.ms_per_triangle", 1), ("costs.mesh.ms_per_triangle", "unknown cost key")),
    (_put("gpus.0.costs.present.cores", 0), ("costs.present.cores", ">= 0.01")),
    (_put("gpus.0.costs.present.cores", 1e5), ("costs.present.cores", "<= 1024")),
    (_put("gpus.0.costs.fragment_loop.ns_per_pixel_iteration", 1e12), ("fragment_loop pass would take",)),
    (_drop("gpus.0.costs.fragment_loop.ns_per_pixel_iteration"), ("ns_per_pixel_iteration", "missing coefficient")),
    (_put("gpus.0.copy.transfr", {}), ("did you mean 'transfer'",)),
    (_put("gpus.0.copy.transfer.h2d_gbps", -1.0), ("copy.transfer.h2d_gbps", "> 0")),
    (_put("gpus.0.copy.transfer.fixed_ns", 1.5), ("copy.transfer.fixed_ns", "integer")),
    (_put("gpus.0.speed", 0), ("gpus[0].speed", "> 0")),
    (_put("gpus.0.speed", float("nan")), ("gpus[0].speed", "finite")),
    (_put("gpus.0.speed", 1e7), ("gpus[0].speed", "<= 1e+06")),
    (_put("gpus.0.task_gap_ns", 10**13), ("gpus[0].task_gap_ns", "<= 1e+12")),
    (_put("gpus.0.cpu_threads", 0), ("gpus[0].cpu_threads", ">= 1")),
    (_put("gpus.0.cpu_threads", 5000), ("gpus[0].cpu_threads", "<= 1024")),
    (_put("gpus.0.local_copy_gbps", float("inf")), ("local_copy_gbps", "finite")),
    (_put("gpu_count", 0), ("gpu_count", ">= 1")),
    (_put("gpu_count", 65), ("gpu_count", "<= 64")),
    (_put("gpu_count", "four"), ("gpu_count", "integer")),
    (_put("peer_links", [{"gpus": [0, 0], "bandwidth_gbps": 1.0, "latency_ns": 1}]), ("peer_links[0].gpus",)),
    (_put("peer_links", [{"gpus": [0, 9], "bandwidth_gbps": 1.0, "latency_ns": 1}]), ("peer_links[0].gpus",)),
    (_put("peer_links", [{"gpus": [True, 1], "bandwidth_gbps": 1.0, "latency_ns": 1}]), ("peer_links[0].gpus",)),
    (_put("peer_links", [{"gpus": [0, 1], "bandwidth_gbps": float("nan"), "latency_ns": 1}]), ("bandwidth_gbps", "finite")),
    (_put("peer_links", [{"gpus": [0, 1], "bandwidth_gbps": 1.0}]), ("peer_links[0].latency_ns", "missing")),
    (_put("peer_links", [{"gpus": [0, 1], "bandwidth_gbps": 1.0, "latency_ns": 1, "lanes": 4}]), ("peer_links[0].lanes",)),
    (_put("peer_mesh", {"bandwidth_gbps": 0, "latency_ns": 1}), ("peer_mesh.bandwidth_gbps", "> 0")),
    (_put("peer_mesh", {"bandwidth_gbps": 1.0}), ("peer_mesh.latency_ns", "missing")),
    (_put("peer_mesh", {"bandwidth_gbps": 1.0, "latency_ns": 1, "gpus": [0, 1]}), ("peer_mesh.gpus", "unknown key")),
]
for _i, (_mutate, _words) in enumerate(PROFILE_CASES):
    def _make(tmp: Path, mutate=_mutate) -> list[str]:
        prof = tc1()
        mutate(prof)
        data = experiment("sf")
        data["profile"] = str(write_toml(tmp / "p.toml", prof))
        return simulate_argv(write_toml(tmp / "e.toml", data), tmp)
    CASES.append(Case(f"profile-{_i}", _make, ("p.toml", *_words)))


# ----- files that are not TOML text ------------------------------------------------------
FILE_CASES: list[tuple[str, bytes | None, tuple[str, ...]]] = [
    ("empty", b"", ("empty",)),
    ("blank", b"  \n\n", ("empty",)),
    ("binary", b"\x00\x01\x02name = 1", ("binary",)),
    ("latin-1", 'name = "caf\xe9"\n'.encode("latin-1"), ("not UTF-8",)),
    ("not-toml", b"name = \n", ("not valid TOML",)),
    ("json", b'{"name": 1}', ("not valid TOML",)),
    ("folder", None, ("is a folder",)),
]
for _id, _content, _words in FILE_CASES:
    def _make_exp(tmp: Path, content=_content) -> list[str]:
        path = tmp / "e.toml"
        if content is None:
            path.mkdir()
        else:
            path.write_bytes(content)
        return simulate_argv(path, tmp)

    def _make_prof(tmp: Path, content=_content) -> list[str]:
        path = tmp / "p.toml"
        if content is None:
            path.mkdir()
        else:
            path.write_bytes(content)
        data = experiment("sf")
        data["profile"] = str(path)
        return simulate_argv(write_toml(tmp / "e.toml", data), tmp)
    CASES.append(Case(f"experiment-file-{_id}", _make_exp, ("e.toml", *_words)))
    if _content is not None:  # a folder as profile is "not found" (below)
        CASES.append(Case(f"profile-file-{_id}", _make_prof, ("p.toml", *_words)))


@case("experiment-missing", "nope.toml", "not found")
def _(tmp: Path) -> list[str]:
    return simulate_argv(tmp / "nope.toml", tmp)


@case("profile-is-a-folder", "profile", "not found")
def _(tmp: Path) -> list[str]:
    (tmp / "p.toml").mkdir()
    data = experiment("sf")
    data["profile"] = str(tmp / "p.toml")
    return simulate_argv(write_toml(tmp / "e.toml", data), tmp)


# ----- output paths, checked before any work ---------------------------------------------
def _file_in_the_way(tmp: Path) -> Path:
    (tmp / "f").write_text("x")
    return tmp / "f"


@case("simulate-out-under-a-file", "--out", "is a file")
def _(tmp: Path) -> list[str]:
    argv = simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp)
    return argv[:3] + [str(_file_in_the_way(tmp) / "sub")]


@case("simulate-out-at-a-file", "--out", "not a folder")
def _(tmp: Path) -> list[str]:
    argv = simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp)
    return argv[:3] + [str(_file_in_the_way(tmp))]


@case("validate-out-at-a-file", "--out", "not a folder")
def _(tmp: Path) -> list[str]:
    return ["validate", str(write_toml(tmp / "e.toml", experiment())), "--measured", str(tmp),
            "--out", str(_file_in_the_way(tmp))]


@case("calibrate-out-is-a-folder", "--out", "is a folder")
def _(tmp: Path) -> list[str]:
    return ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--out", str(tmp)]


@case("calibrate-out-under-a-file", "--out", "is a file")
def _(tmp: Path) -> list[str]:
    return ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--out", str(_file_in_the_way(tmp) / "p.toml")]


@case("run-out-under-a-file", "--out", "is a file")
def _(tmp: Path) -> list[str]:
    return ["run", str(write_toml(tmp / "e.toml", experiment())), "--out", str(_file_in_the_way(tmp) / "m")]


@case("measure-out-under-a-file", "--out", "is a file")
def _(tmp: Path) -> list[str]:
    return ["measure", "--pass", "mesh", "--out", str(_file_in_the_way(tmp) / "m.csv")]


@case("simulate-out-unwritable", "--out", "not writable")
def _(tmp: Path) -> list[str]:
    argv = simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp)
    return argv[:3] + [str(_unwritable(tmp) / "out")]


def _unwritable(tmp: Path) -> Path:
    """A folder this process cannot create files in (a read-only mode; as root, /sys)."""
    folder = tmp / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        (folder / "probe").touch()
    except OSError:
        return folder
    (folder / "probe").unlink()
    return Path("/sys")


# ----- run and measure: argument checks before any device --------------------------------
RUN_CASES = [
    (["--gpus-per-device", "0"], ("--gpus-per-device", ">= 1")),
    (["--gpus-per-device", "1", "--devices", "0,1"], ("not both",)),
    (["--devices", "a,b"], ("--devices", "integers")),
    (["--devices=-1,0"], ("--devices", ">= 0")),
    (["--lp-threads", "0"], ("--lp-threads",)),
    (["--lp-threads", "1,,2"], ("--lp-threads", "integers")),
    (["--host-threads", "0"], ("--host-threads",)),
    (["--host-threads", "100000"], ("--host-threads",)),
    (["--prewarm", "-1"], ("--prewarm",)),
    (["--set", "schedule.gpus=9"], ("schedule.gpus",)),
    (["--format", "xlsx"], ("--format", "invalid choice")),
    (["--prewarm", "many"], ("--prewarm", "invalid int")),
]
for _i, (_args, _words) in enumerate(RUN_CASES):
    def _make(tmp: Path, args=_args) -> list[str]:
        return ["run", str(write_toml(tmp / "e.toml", experiment())), "--out", str(tmp / "out"), *args]
    CASES.append(Case(f"run-args-{_i}", _make, _words))

MEASURE_CASES = [
    ([], ("--pass",)),
    (["--pass", "mesh"], ("--out",)),
    (["--pass", "mesh", "--out", "OUT.txt"], ("--out", ".csv or .parquet")),
    (["--pass", "mesh", "--out", "OUT.csv", "--reps", "0"], ("--reps", ">= 1")),
    (["--pass", "mesh", "--out", "OUT.csv", "--gpus", "0"], ("--gpus", ">= 1")),
    (["--pass", "mesh", "--out", "OUT.csv", "--warmup", "-1"], ("--warmup", ">= 0")),
    (["--pass", "meshh", "--out", "OUT.csv"], ("--pass", "unknown pass")),
    (["--pass", "mesh", "--out", "OUT.csv", "--sweep", "triangels=1,2"], ("--sweep", "no parameter")),
    (["--pass", "mesh", "--out", "OUT.csv", "--sweep", "triangles"], ("--sweep", "PARAM=")),
    (["--pass", "mesh", "--out", "OUT.csv", "--sweep", "triangles=1,x"], ("triangles", "integer")),
    (["--pass", "mesh", "--out", "OUT.csv", "--reps", "x"], ("--reps", "invalid int")),
]
for _i, (_args, _words) in enumerate(MEASURE_CASES):
    def _make(tmp: Path, args=_args) -> list[str]:
        return ["measure", *[a.replace("OUT", str(tmp / "out")) for a in args]]
    CASES.append(Case(f"measure-args-{_i}", _make, _words))


# ----- validate --measured: measured-run folders -----------------------------------------
def measured_folder(tmp: Path, key: str = "sf", sets: dict[str, Any] | None = None) -> Path:
    """A measured-run folder as `mgpusim run` writes it, made from a simulation (no device)."""
    folder = tmp / "measured"
    folder.mkdir()
    exp = load_experiment(write_toml(tmp / "m.toml", experiment(key)),
                          {"schedule.frames": 14, **(sets or {})})
    result = simulate(exp, record_trace=True)
    result.trace.to_csv(folder / "trace.csv", index=False)
    (folder / "summary.json").write_text(json.dumps({"config": {**result.config, "measured": True}},
                                                    default=list))
    return folder


def validate_argv(tmp: Path, folder: Path, *sets: str) -> list[str]:
    exp = write_toml(tmp / "e.toml", experiment("sf"))
    return ["validate", str(exp), "--measured", str(folder), "--out", str(tmp / "out"),
            "--set", "schedule.frames=14", *[a for s in sets for a in ("--set", s)]]


def _edit_trace(edit: Callable[[pd.DataFrame], pd.DataFrame | None]) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        folder = measured_folder(tmp)
        df = pd.read_csv(folder / "trace.csv", keep_default_na=False)
        df = edit(df)
        df.to_csv(folder / "trace.csv", index=False)
        return validate_argv(tmp, folder)
    return make


def _write(name: str, content: bytes) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        folder = measured_folder(tmp)
        (folder / name).write_bytes(content)
        return validate_argv(tmp, folder)
    return make


def _set_col(col: str, row: int, value: Any) -> Callable[[pd.DataFrame], pd.DataFrame]:
    def edit(df: pd.DataFrame) -> pd.DataFrame:
        df[col] = df[col].astype(object)
        df.loc[row, col] = value
        return df
    return edit


MEASURED_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("trace-binary", _write("trace.csv", b"\x00\xff\xfe" * 50), ("trace.csv",)),
    ("trace-empty", _write("trace.csv", b""), ("trace.csv", "empty")),
    ("trace-header-only", _write("trace.csv", b"frame,device,engine,step,task,start_ns,end_ns,bytes,waits_for\n"), ("no rows",)),
    ("trace-latin-1", _write("trace.csv", "frame,step\n1,caf\xe9\n".encode("latin-1")), ("trace.csv", "UTF-8")),
    ("trace-wrong-columns", _write("trace.csv", b"a,b,c\n1,2,3\n"), ("trace.csv", "missing column")),
    ("trace-truncated", _edit_trace(lambda df: df.iloc[:, :5]), ("missing column",)),
    ("trace-end-before-start", _edit_trace(_set_col("end_ns", 3, -0)), ("end_ns",)),
    ("trace-nan-time", _edit_trace(_set_col("start_ns", 2, "nan")), ("start_ns", "whole numbers")),
    ("trace-text-time", _edit_trace(_set_col("end_ns", 2, "soon")), ("end_ns", "whole numbers")),
    ("trace-fraction-time", _edit_trace(_set_col("end_ns", 2, 1.5)), ("end_ns", "whole numbers")),
    ("trace-negative-frame", _edit_trace(_set_col("frame", 1, -3)), ("frame", ">= 0")),
    ("trace-huge-time", _edit_trace(_set_col("end_ns", 1, "99999999999999999999999")), ("end_ns",)),
    ("summary-not-json", _write("summary.json", b"{not json"), ("summary.json", "not valid JSON")),
    ("summary-binary", _write("summary.json", b"\xff\x00\x01"), ("summary.json", "not UTF-8")),
    ("summary-list", _write("summary.json", b"[1, 2]"), ("summary.json", "JSON object")),
    ("summary-config-list", _write("summary.json", b'{"config": [1]}'), ("summary.json", "config")),
]


def _parquet_case(tmp: Path) -> list[str]:
    folder = measured_folder(tmp)
    (folder / "trace.csv").unlink()
    (folder / "trace.parquet").write_bytes(b"PAR1 this is not parquet PAR1")
    return validate_argv(tmp, folder)


MEASURED_CASES.append(("trace-corrupt-parquet", _parquet_case, ("trace.parquet", "Parquet")))


def _mismatch(sets: dict[str, Any], *argv_sets: str) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        return validate_argv(tmp, measured_folder(tmp, sets=sets), *argv_sets)
    return make


MEASURED_CASES += [
    ("mismatch-iterations", _mismatch({"scene.passes.0.iterations": 4000}), ("config.inputs.passes[0].iterations", "4000")),
    ("mismatch-host-copy", _mismatch({"schedule.host_copy": False}), ("config.host_copy",)),
    ("mismatch-gpus", _mismatch({"schedule.gpus": 3}), ("config.gpus",)),
    ("mismatch-width", _mismatch({"scene.width": 512}), ("config.width",)),
    ("mismatch-buffers", _mismatch({"schedule.buffers": 3}), ("buffers",)),
    ("mismatch-frames-in-flight", _mismatch({"schedule.frames_in_flight": 1}), ("frames_in_flight",)),
    ("mismatch-passes", _mismatch({}, 'scene.passes=[{name="a",kind="fragment_loop",iterations=1},'
                                      '{name="b",kind="present"}]'), ("config.inputs.passes", "entries")),
    ("mismatch-output-bytes", _mismatch({}, "scene.passes.0.output_bytes=5"), ("output_bytes",)),
    # any key both sides record: the scene's byte sizes, the schedule's own record, names
    ("mismatch-color-bytes", _mismatch({"scene.color_bytes_per_pixel": 8}), ("color_bytes_per_pixel", "another configuration")),
    ("mismatch-depth-bytes", _mismatch({"scene.depth_bytes_per_pixel": 4}), ("config.inputs.scene.depth_bytes_per_pixel",)),
    ("mismatch-dataset-bytes", _mismatch({"scene.dataset_bytes": 1000}), ("config.inputs.scene.dataset_bytes",)),
    ("mismatch-tile-rows", _mismatch({"schedule.tile_rows": [400, 368]}), ("tile_rows",)),
    ("mismatch-pipelining", _mismatch({"schedule.pipelining": "lockstep"}), ("config.inputs.schedule.pipelining",)),
    ("mismatch-pass-name", _mismatch({"scene.passes.0.name": "other"}), ("config.inputs.passes[0].name",)),
    ("mismatch-another-experiment", lambda tmp: validate_argv(tmp, measured_folder(tmp, "sl")),
     ("config.", "other key(s) differ too", "config.schedule")),
    ("mismatch-several-named", _mismatch({"scene.width": 512, "scene.passes.0.iterations": 4000}),
     ("config.width", "other key(s) differ too", "config.inputs.passes[0].iterations",
      "config.contribution_bytes_per_frame")),
]


def _old_run(sets: dict[str, Any]) -> Callable[[Path], list[str]]:
    """A run recorded before the inputs were (no config.inputs): its schedule's own record
    (bytes per frame, tile rows) is still compared."""
    def make(tmp: Path) -> list[str]:
        folder = measured_folder(tmp, sets=sets)
        summary = json.loads((folder / "summary.json").read_text())
        del summary["config"]["inputs"]
        (folder / "summary.json").write_text(json.dumps(summary))
        return validate_argv(tmp, folder)
    return make


def _no_summary(tmp: Path) -> list[str]:
    folder = measured_folder(tmp)
    (folder / "summary.json").unlink()
    return validate_argv(tmp, folder)


MEASURED_CASES += [
    ("old-run-color-bytes", _old_run({"scene.color_bytes_per_pixel": 8}), ("config.contribution_bytes_per_frame",)),
    ("old-run-tile-rows", _old_run({"schedule.tile_rows": [400, 368]}), ("config.tile_rows",)),
    ("no-summary", _no_summary, ("measured", "no summary.json")),
]


@case("measured-folder-missing", "measured", "not a folder")
def _(tmp: Path) -> list[str]:
    return validate_argv(tmp, tmp / "nothing")


@case("measured-folder-without-trace", "no trace")
def _(tmp: Path) -> list[str]:
    (tmp / "m").mkdir()
    return validate_argv(tmp, tmp / "m")


for _id, _make, _words in MEASURED_CASES:
    CASES.append(Case(f"measured-{_id}", _make, _words))


# ----- calibrate: measure tables ---------------------------------------------------------
def _table(edit: Callable[[pd.DataFrame], pd.DataFrame], source: str = "mesh.csv",
           name: str = "t.csv") -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        df = pd.read_csv(ROOT / "data" / "lavapipe" / source)
        path = tmp / name
        edited = edit(df)
        if name.endswith(".parquet"):
            edited.to_parquet(path, index=False)
        else:
            edited.to_csv(path, index=False)
        return ["calibrate", str(path), "--out", str(tmp / "out" / "p.toml")]
    return make


def _raw_table(content: bytes, name: str = "t.csv") -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        (tmp / name).write_bytes(content)
        return ["calibrate", str(tmp / name), "--out", str(tmp / "out" / "p.toml")]
    return make


CALIBRATE_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("nan-duration", _table(_set_col("duration_ns", 3, float("nan"))), ("duration_ns", "finite")),
    ("nan-duration-all", _table(lambda df: df.assign(duration_ns=float("nan"))), ("duration_ns", "finite")),
    ("inf-duration", _table(_set_col("duration_ns", 0, "inf")), ("duration_ns", "finite")),
    ("negative-duration", _table(_set_col("duration_ns", 5, -100)), ("duration_ns", "> 0")),
    ("zero-duration", _table(_set_col("duration_ns", 5, 0)), ("duration_ns", "> 0")),
    ("text-duration", _table(_set_col("duration_ns", 1, "slow")), ("duration_ns",)),
    ("header-only", _table(lambda df: df.iloc[:0]), ("no rows",)),
    ("unknown-pass", _table(_set_col("pass", 0, "mesh_v2")), ("unknown pass 'mesh_v2'", "did you mean 'mesh'")),
    ("no-pass-column", _table(lambda df: df.drop(columns=["pass"])), ("no 'pass' column",)),
    ("no-duration-column", _table(lambda df: df.drop(columns=["duration_ns"])), ("no 'duration_ns' column",)),
    ("missing-param-column", _table(lambda df: df.drop(columns=["triangles"])), ("triangles",)),
    ("missing-param-value", _table(_set_col("triangles", 2, float("nan"))), ("triangles",)),
    ("negative-param", _table(_set_col("width", 2, -5)), ("width", ">= 0")),
    ("nan-param-text", _table(_set_col("width", 2, "wide")), ("width",)),
    ("host-copy-no-threads", _table(lambda df: df.drop(columns=["threads"]), "host_copy.csv"), ("threads",)),
    ("copy-no-bytes", _table(lambda df: df.drop(columns=["bytes"]), "copy_h2d.csv"), ("bytes",)),
    ("parquet-nan", _table(_set_col("duration_ns", 3, float("nan")), name="t.parquet"), ("duration_ns", "finite")),
    ("empty-file", _raw_table(b""), ("empty",)),
    ("binary-file", _raw_table(b"\x00\x01\xff\xfe" * 40), ("t.csv",)),
    ("corrupt-parquet", _raw_table(b"PAR1 nope PAR1", "t.parquet"), ("Parquet",)),
    ("missing-file", lambda tmp: ["calibrate", str(tmp / "nope.csv"), "--out", str(tmp / "out" / "p.toml")], ("not found",)),
    ("folder", lambda tmp: ["calibrate", str(tmp), "--out", str(tmp / "out" / "p.toml")], ("not found",)),
    ("nothing-to-fit", _table(lambda df: df.assign(gpus=2)), ("nothing to fit",)),
    ("gpus-zero", lambda tmp: ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--gpus", "0",
                               "--out", str(tmp / "out" / "p.toml")], ("--gpus",)),
]


def _bad_machine(tmp: Path) -> list[str]:
    df = pd.read_csv(ROOT / "data" / "lavapipe" / "mesh.csv")
    df.to_csv(tmp / "t.csv", index=False)
    (tmp / "t.csv.machine.json").write_text("{oops")
    return ["calibrate", str(tmp / "t.csv"), "--out", str(tmp / "out" / "p.toml")]


def _bad_base(content: bytes) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        (tmp / "base.toml").write_bytes(content)
        return ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--base", str(tmp / "base.toml"),
                "--out", str(tmp / "out" / "p.toml")]
    return make


CALIBRATE_CASES += [
    ("machine-json-corrupt", _bad_machine, ("machine.json", "not valid JSON")),
    ("base-binary", _bad_base(b"\x00\x01"), ("base.toml", "binary")),
    ("base-bad-field", _bad_base((ROOT / "hardware_profiles" / "tc1.toml").read_bytes()
                                 .replace(b"memcpy_threads = 12", b"memcpy_threads = -2")),
     ("base.toml", "host.memcpy_threads")),
]
for _id, _make, _words in CALIBRATE_CASES:
    CASES.append(Case(f"calibrate-{_id}", _make, _words))


# ----- study files ------------------------------------------------------------------------
def _study(edit: Callable[[str], str]) -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        text = (ROOT / "experiments" / "h100" / "study.toml").read_text()
        text = text.replace('"../../', f'"{os.path.relpath(ROOT, tmp)}/')  # paths stay relative
        (tmp / "s.toml").write_text(edit(text))
        return ["study", "calibrate", str(tmp / "s.toml"), "--out", str(tmp / "out")]
    return make


STUDY_CASES = [
    ("unknown-key", _study(lambda t: t.replace("description =", "descripton =")), ("did you mean 'description'",)),
    ("empty", _study(lambda t: ""), ("empty",)),
    ("binary", _study(lambda t: "\0" + t), ("binary",)),
    ("not-toml", _study(lambda t: t + "\n[calibration\n"), ("not valid TOML",)),
]
for _id, _make, _words in STUDY_CASES:
    CASES.append(Case(f"study-{_id}", _make, ("s.toml", *_words)))


# ----- study files: a small study whose every part is set, then one part broken ------------
def mini_study(tmp: Path) -> dict[str, Any]:
    """A study with every section (tables, a host copy table, a recipe, both halves), its paths
    relative to `tmp` where it is written; it loads (see the positive control below)."""
    r = os.path.relpath(ROOT, tmp)
    exp = f"{r}/experiments/sort_first_tc1.toml"
    return {"name": "mini", "description": "a study", "profile": f"{r}/hardware_profiles/tc1.toml",
            "microbenchmarks": {"tables": f"{r}/data/lavapipe", "files": ["fragment_loop.csv", "mesh.csv"],
                                "sweeps": {"mesh": {"width": [128], "triangles": [1000, 2000]}}},
            "runs": {"repeats": 1, "max_frames": 100},
            "calibration": {"host_copy_table": "host_copy.csv", "run_fitted": ["fragment_loop"],
                            "run_fit_terms": ["pixel"], "run_fit_gpus": 1,
                            "copy_from": {"profile": f"{r}/hardware_profiles/h200_x2.toml",
                                          "costs": ["present"], "host": ["dispatch_ns"]},
                            "host_grid": {"dispatch_ns": [0, 1000]},
                            "config": [{"name": "a", "experiment": exp, "set": ["schedule.gpus=2"]}]},
            "held_out": {"config": [{"name": "b", "experiment": exp, "set": []}]}}


def _mini(mutate: Callable[[dict], None], step: str = "validate") -> Callable[[Path], list[str]]:
    def make(tmp: Path) -> list[str]:
        data = mini_study(tmp)
        mutate(data)
        write_toml(tmp / "s.toml", data)
        return ["study", step, str(tmp / "s.toml"), "--out", str(tmp / "out")]
    return make


def _abs(path: str) -> Callable[[dict], None]:
    """Set `path` to the absolute form of the (relative) path it holds."""
    def mutate(data: dict) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        node[last] = str((ROOT / "tests" / node[last]).resolve())  # any absolute path
    return mutate


CFG = "calibration.config.0"
MINI_STUDY_CASES: list[tuple[str, Callable[[dict], None], tuple[str, ...]]] = [
    ("name-parent", _put("name", "../x"), ("name", "separator")),
    ("name-absolute", _put("name", "/tmp/x"), ("name", "separator")),
    ("name-dotdot", _put("name", ".."), ("name", "'..'")),
    ("name-nul", _put("name", "a\0b"), ("name", "NUL")),
    ("name-number", _put("name", 5), ("name", "string")),
    ("name-blank", _put("name", "  "), ("name", "empty")),
    ("config-name-parent", _put(f"{CFG}.name", "../../escape"), ("calibration.config[0].name", "separator")),
    ("config-name-absolute", _put(f"{CFG}.name", "/tmp/escape"), ("calibration.config[0].name", "separator")),
    ("config-name-dotdot", _put(f"{CFG}.name", ".."), ("calibration.config[0].name",)),
    ("config-name-dot", _put(f"{CFG}.name", "."), ("calibration.config[0].name",)),
    ("config-name-backslash", _put(f"{CFG}.name", "a\\b"), ("calibration.config[0].name", "separator")),
    ("config-name-nul", _put(f"{CFG}.name", "a\0"), ("calibration.config[0].name", "NUL")),
    ("config-name-newline", _put(f"{CFG}.name", "a\nb"), ("calibration.config[0].name", "control")),
    ("config-name-long", _put(f"{CFG}.name", "x" * 300), ("calibration.config[0].name", "255 bytes")),
    ("config-name-empty", _put(f"{CFG}.name", ""), ("calibration.config[0].name", "empty")),
    ("config-name-list", _put(f"{CFG}.name", ["a"]), ("calibration.config[0].name", "string")),
    ("config-name-missing", _drop(f"{CFG}.name"), ("calibration.config[0].name", "missing")),
    ("held-name-parent", _put("held_out.config.0.name", "../b"), ("held_out.config[0].name", "separator")),
    ("config-set-string", _put(f"{CFG}.set", "schedule.gpus=2"), ("calibration.config[0].set", "a list")),
    ("config-set-number", _put(f"{CFG}.set", [3]), ("calibration.config[0].set[0]", "string")),
    ("config-set-table", _put(f"{CFG}.set", [{"a": 1}]), ("calibration.config[0].set[0]", "string")),
    ("config-set-nested", _put(f"{CFG}.set", [["schedule.gpus=2"]]), ("calibration.config[0].set[0]",)),
    ("config-set-no-equals", _put(f"{CFG}.set", ["schedule.gpus"]), ("calibration.config[0].set[0]", "key=value")),
    ("config-set-no-key", _put(f"{CFG}.set", ["=2"]), ("calibration.config[0].set[0]", "no key")),
    ("config-set-misspelt", _put(f"{CFG}.set", ["schedule.gpuz=2"]), ("calibration.config[0]", "did you mean 'gpus'")),
    ("config-set-bad-value", _put(f"{CFG}.set", ["schedule.gpus=9"]), ("calibration.config[0]", "schedule.gpus")),
    ("config-set-bool", _put(f"{CFG}.set", True), ("calibration.config[0].set", "a list")),
    ("config-experiment-absolute", _abs(f"{CFG}.experiment"), ("calibration.config[0].experiment", "absolute")),
    ("config-experiment-missing-file", _put(f"{CFG}.experiment", "nope.toml"), ("experiment", "does not exist")),
    ("config-experiment-number", _put(f"{CFG}.experiment", 5), ("experiment", "string")),
    ("config-experiment-absent", _drop(f"{CFG}.experiment"), ("experiment", "missing")),
    ("config-unknown-key", _put(f"{CFG}.sets", []), ("calibration.config[0].sets", "did you mean 'set'")),
    ("config-not-a-table", _put("calibration.config", [5]), ("calibration.config[0]", "table")),
    ("config-empty-array", _put("held_out.config", []), ("held_out.config", "empty")),
    ("config-duplicate", _put("held_out.config.0.name", "a"), ("unique", "a")),
    ("profile-absolute", _abs("profile"), ("profile", "absolute")),
    ("profile-missing", _drop("profile"), ("profile", "missing")),
    ("profile-blank", _put("profile", " "), ("profile", "relative")),
    ("profile-nope", _put("profile", "nope.toml"), ("profile", "does not exist")),
    ("files-string", _put("microbenchmarks.files", "mesh.csv"), ("microbenchmarks.files", "a list")),
    ("files-empty", _put("microbenchmarks.files", []), ("microbenchmarks.files", "empty list")),
    ("files-number", _put("microbenchmarks.files", [1]), ("microbenchmarks.files[0]", "string")),
    ("files-parent", _put("microbenchmarks.files", ["../../../../etc/passwd"]), ("files[0]", "inside")),
    ("files-absolute", _put("microbenchmarks.files", ["/etc/hostname"]), ("files[0]", "inside")),
    ("files-nope", _put("microbenchmarks.files", ["nope.csv"]), ("files[0]", "does not exist")),
    ("files-folder", _put("microbenchmarks.files", ["history"]), ("files[0]", "not a file")),
    ("files-without-tables", _drop("microbenchmarks.tables"), ("microbenchmarks.files", "go together")),
    ("tables-without-files", _drop("microbenchmarks.files"), ("microbenchmarks.tables", "go together")),
    ("tables-absolute", _abs("microbenchmarks.tables"), ("microbenchmarks.tables", "absolute")),
    ("tables-a-file", lambda d: d["microbenchmarks"].update(tables=d["microbenchmarks"]["tables"] + "/mesh.csv"),
     ("microbenchmarks.tables", "not a folder")),
    ("tables-number", _put("microbenchmarks.tables", 3), ("microbenchmarks.tables", "string")),
    ("sweep-scalar", _put("microbenchmarks.sweeps.mesh.width", 128), ("microbenchmarks.sweeps.mesh.width", "a list")),
    ("sweep-string", _put("microbenchmarks.sweeps.mesh.width", "128"), ("sweeps.mesh.width", "a list")),
    ("sweep-empty", _put("microbenchmarks.sweeps.mesh.width", []), ("sweeps.mesh.width", "empty list")),
    ("sweep-nested", _put("microbenchmarks.sweeps.mesh.width", [[128]]), ("sweeps.mesh.width[0]",)),
    ("sweep-table-value", _put("microbenchmarks.sweeps.mesh.width", [{"a": 1}]), ("sweeps.mesh.width[0]",)),
    ("sweep-nan", _put("microbenchmarks.sweeps.mesh.width", [float("nan")]), ("sweeps.mesh.width[0]",)),
    ("sweep-unknown-pass", _put("microbenchmarks.sweeps.msh", {"width": [1]}), ("sweeps.msh", "did you mean 'mesh'")),
    ("sweep-no-params", _put("microbenchmarks.sweeps.mesh", {}), ("sweeps.mesh", "empty sweep")),
    ("sweep-not-a-table", _put("microbenchmarks.sweeps.mesh", 3), ("sweeps.mesh", "table")),
    ("sweeps-not-a-table", _put("microbenchmarks.sweeps", [1]), ("microbenchmarks.sweeps", "table")),
    ("pairs-scalar", _put("microbenchmarks.pairs", {"mesh": {"width": 1}}), ("microbenchmarks.pairs.mesh.width", "a list")),
    ("rounds-zero", _put("microbenchmarks.rounds", 0), ("microbenchmarks.rounds", ">= 1")),
    ("reps-float", _put("microbenchmarks.reps", 2.5), ("microbenchmarks.reps", "integer")),
    ("run-fitted-unknown", _put("calibration.run_fitted", ["fragmnt_loop"]), ("calibration.run_fitted", "did you mean 'fragment_loop'")),
    ("run-fitted-string", _put("calibration.run_fitted", "present"), ("calibration.run_fitted", "a list")),
    ("run-fitted-empty", _put("calibration.run_fitted", []), ("calibration.run_fitted", "empty list")),
    ("run-fitted-number", _put("calibration.run_fitted", [5]), ("calibration.run_fitted[0]", "string")),
    ("run-fit-terms-unknown", _put("calibration.run_fit_terms", ["pixels"]), ("calibration.run_fit_terms", "did you mean 'pixel'")),
    ("run-fit-terms-empty", _put("calibration.run_fit_terms", []), ("calibration.run_fit_terms", "empty list")),
    ("run-fit-terms-string", _put("calibration.run_fit_terms", "pixel"), ("calibration.run_fit_terms", "a list")),
    ("run-fit-terms-kind", _put("calibration.run_fit_terms", ["mesh"]), ("calibration.run_fit_terms", "unknown work term")),
    ("run-fit-alone-unknown", _put("calibration.run_fit_alone", ["composite"]), ("calibration.run_fit_alone", "unknown pass kind")),
    ("run-fit-gpus-negative", _put("calibration.run_fit_gpus", -1), ("calibration.run_fit_gpus", ">= 0")),
    ("run-fit-gpus-huge", _put("calibration.run_fit_gpus", 1000), ("calibration.run_fit_gpus", "<= 64")),
    ("host-copy-table-nope", _put("calibration.host_copy_table", "nope.csv"), ("calibration.host_copy_table", "does not exist")),
    ("host-copy-table-parent", _put("calibration.host_copy_table", "../x.csv"), ("calibration.host_copy_table", "inside")),
    ("host-copy-table-number", _put("calibration.host_copy_table", 5), ("calibration.host_copy_table", "string")),
    ("copy-from-cost-unknown", _put("calibration.copy_from.costs", ["nope"]), ("calibration.copy_from.costs", "not in")),
    ("copy-from-host-misspelt", _put("calibration.copy_from.host", ["dispatch"]), ("copy_from.host", "did you mean 'dispatch_ns'")),
    ("copy-from-costs-string", _put("calibration.copy_from.costs", "present"), ("copy_from.costs", "a list")),
    ("copy-from-no-profile", _drop("calibration.copy_from.profile"), ("copy_from.costs", "needs copy_from.profile")),
    ("copy-from-profile-nope", _put("calibration.copy_from.profile", "nope.toml"), ("copy_from.profile", "does not exist")),
    ("copy-from-unknown-key", _put("calibration.copy_from.cost", []), ("copy_from.cost", "did you mean 'costs'")),
    ("host-grid-scalar", _put("calibration.host_grid.dispatch_ns", 5), ("calibration.host_grid.dispatch_ns", "a list")),
    ("host-grid-empty", _put("calibration.host_grid.dispatch_ns", []), ("host_grid.dispatch_ns", "empty list")),
    ("host-grid-text", _put("calibration.host_grid.dispatch_ns", ["a"]), ("host_grid.dispatch_ns[0]", "numbers")),
    ("host-grid-bool", _put("calibration.host_grid.dispatch_ns", [True]), ("host_grid.dispatch_ns[0]", "numbers")),
    ("host-grid-inf", _put("calibration.host_grid.dispatch_ns", [float("inf")]), ("host_grid.dispatch_ns[0]",)),
    ("host-grid-misspelt", _put("calibration.host_grid.dispatch", [1]), ("host_grid.dispatch", "did you mean 'dispatch_ns'")),
    ("calibration-runs-nope", _put("calibration.runs", "nope"), ("calibration.runs", "does not exist")),
    ("calibration-runs-absolute", lambda d: d["calibration"].update(runs=str(ROOT)), ("calibration.runs", "absolute")),
    ("held-out-runs-number", _put("held_out.runs", 5), ("held_out.runs", "string")),
    ("held-out-runs-file", lambda d: d["held_out"].update(runs=d["profile"]), ("held_out.runs", "not a folder")),
    ("runs-repeats-zero", _put("runs.repeats", 0), ("runs.repeats", ">= 1")),
    ("runs-max-frames-text", _put("runs.max_frames", "x"), ("runs.max_frames", "integer")),
    ("threads-per-core-huge", _put("lavapipe_threads_per_core", 100), ("lavapipe_threads_per_core", "<= 16")),
    ("base-unknown", _put("calibration.base", "gpu"), ("calibration.base", "one of")),
    ("top-unknown-key", _put("descripion", "x"), ("descripion", "did you mean 'description'")),
    ("calibration-not-a-table", _put("calibration", 5), ("calibration", "table")),
]
for _id, _mutate, _words in MINI_STUDY_CASES:
    CASES.append(Case(f"study-{_id}", _mini(_mutate), ("s.toml", *_words)))
for _step in ("calibrate", "measure", "run"):  # every step checks the file before its work
    CASES.append(Case(f"study-{_step}-config-name-parent", _mini(_put(f"{CFG}.name", "../x"), _step),
                      ("calibration.config[0].name", "separator")))


# ----- sweep arguments: refused before any point runs or any folder is made ---------------
SWEEP = str(ROOT / "experiments" / "sort_first_tc1.toml")


def sweep_argv(tmp: Path, *args: str, grid: tuple[str, ...] = ("schedule.gpus=1,2",)) -> list[str]:
    return ["sweep", SWEEP, *[a for g in grid for a in ("--grid", g)], *args, "--out", str(tmp / "out"),
            "--workers", "1", "--no-progress"]


SWEEP_CASES: list[tuple[str, tuple[str, ...], tuple[str, ...], tuple[str, ...]]] = [
    # (id, extra arguments, grid, words)
    ("dask-words", ("--dask", "not an address"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-scheme-only", ("--dask", "tcp://"), ("schedule.gpus=1,2",), ("--dask", "'tcp://'")),
    ("dask-port-text", ("--dask", "tcp://127.0.0.1:notaport"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-port-huge", ("--dask", "127.0.0.1:99999"), ("schedule.gpus=1,2",), ("--dask", "1-65535")),
    ("dask-port-zero", ("--dask", "127.0.0.1:0"), ("schedule.gpus=1,2",), ("--dask", "1-65535")),
    ("dask-http", ("--dask", "http://127.0.0.1:8786"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-no-port", ("--dask", "tcp://127.0.0.1"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-no-host", ("--dask", ":8786"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-path", ("--dask", "tcp://127.0.0.1:8786/x"), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("dask-empty", ("--dask", ""), ("schedule.gpus=1,2",), ("--dask", "HOST:PORT")),
    ("metric-text", ("--metric", "fidelity"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-list", ("--metric", "modelled_effects"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-list-item", ("--metric", "modelled_effects.0"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-bool", ("--metric", "effects.link_model"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-why", ("--metric", "fast_forward.why"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-error", ("--metric", "error"), ("schedule.gpus=1,2",), ("--metric", "not a number")),
    ("metric-misspelt", ("--metric", "frame_tme_ms"), ("schedule.gpus=1,2",), ("--metric", "did you mean 'frame_time_ms'")),
    ("metric-fsp", ("--metric", "fsp"), ("schedule.gpus=1,2",), ("--metric", "not a summary field")),
    ("metric-case", ("--metric", "Frame_Time_ms"), ("schedule.gpus=1,2",), ("--metric", "not a summary field")),
    ("metric-empty", ("--metric", ""), ("schedule.gpus=1,2",), ("--metric", "not a summary field")),
    ("metric-group", ("--metric", "utilization"), ("schedule.gpus=1,2",), ("--metric", "utilization.<member>")),
    ("metric-group-dot", ("--metric", "utilization."), ("schedule.gpus=1,2",), ("--metric", "not a summary field")),
    ("metric-key", ("--metric", "schedule.gpus"), ("schedule.gpus=1,2",), ("--metric", "not a summary field")),
    ("grid-point", (), ("point=1,2",), ("--grid point", "column")),
    ("grid-error", (), ("error=1,2",), ("--grid error", "column")),
    ("grid-wall-s", (), ("wall_s=1,2",), ("--grid wall_s", "column")),
    ("grid-frame-time", (), ("frame_time_ms=1,2",), ("--grid frame_time_ms", "column")),
    ("grid-fps", (), ("fps=1,2",), ("--grid fps", "column")),
    ("grid-utilization", (), ("utilization.gpu0.graphics=1,2",), ("--grid utilization.gpu0.graphics", "column")),
    ("grid-memory", (), ("memory.gpu0.used_bytes=1",), ("--grid memory.gpu0.used_bytes", "column")),
    ("grid-fidelity", (), ("fidelity=full",), ("--grid fidelity", "column")),
    ("grid-effects", (), ("modelled_effects=a",), ("--grid modelled_effects", "column")),
    ("grid-million", (), (f"scene.width={','.join(map(str, range(1, 1001)))}",
                          f"scene.height={','.join(map(str, range(1, 1001)))}"), ("--grid", "1,000,000 points", "100,000")),
    ("grid-one-key-huge", (), (f"scene.passes.0.iterations={','.join(map(str, range(1, 100_002)))}",),
     ("--grid", "100,001 points")),
    ("grid-many-keys", (), tuple(f"k{i}=1,2,3,4" for i in range(10)), ("--grid", "1,048,576 points")),
    ("grid-duplicate-value", (), ("schedule.gpus=1,1",), ("--grid schedule.gpus", "given twice")),
    ("grid-duplicate-text", (), ('schedule.name="afr","afr"',), ("--grid schedule.name", "given twice")),
    ("grid-also-set", ("--set", "schedule.gpus=2"), ("schedule.gpus=1,2",), ("--grid schedule.gpus", "--set")),
    ("grid-no-values", (), ("schedule.gpus=",), ("--grid", "KEY=V1")),
    ("grid-only-commas", (), ("schedule.gpus=,,",), ("--grid", "KEY=V1")),
    ("grid-no-key", (), ("=1,2",), ("--grid", "KEY=V1")),
    ("grid-no-equals", (), ("schedule.gpus",), ("--grid", "KEY=V1")),
    ("grid-key-twice", (), ("schedule.gpus=1", "schedule.gpus=2"), ("--grid", "given twice")),
    ("grid-misspelt", (), ("schedule.gpuz=1,2",), ("--grid schedule.gpuz", "did you mean 'gpus'")),
    ("grid-no-value-loads", (), ("schedule.gpus=0,-1",), ("--grid schedule.gpus", "no value")),
    ("grid-value-nan", (), ("scene.width=nan",), ("--grid scene.width",)),
    ("workers-zero", ("--workers", "0"), ("schedule.gpus=1,2",), ("--workers", "1..256")),
    ("workers-negative", ("--workers=-3",), ("schedule.gpus=1,2",), ("--workers",)),
    ("workers-huge", ("--workers", "100000"), ("schedule.gpus=1,2",), ("--workers", "1..256")),
    ("workers-text", ("--workers", "x"), ("schedule.gpus=1,2",), ("--workers", "invalid")),
    ("fidelity-unknown", ("--fidelity", "fast"), ("schedule.gpus=1,2",), ("--fidelity", "analytic")),
    ("set-misspelt", ("--set", "schedule.gpuz=2"), ("schedule.gpus=1,2",), ("schedule.gpuz", "did you mean 'gpus'")),
    ("set-no-key", ("--set", "=3"), ("schedule.gpus=1,2",), ("--set", "no key")),
    ("set-broken-base", ("--set", "schedule.warmup_frames=1000"), ("schedule.gpus=1,2",), ("warmup_frames",)),
]
for _id, _args, _grid, _words in SWEEP_CASES:
    def _make(tmp: Path, args=_args, grid=_grid) -> list[str]:
        argv = sweep_argv(tmp, *args, grid=grid)
        if "--workers" in args or any(a.startswith("--workers=") for a in args):  # the case's own
            i = len(argv) - 3
            del argv[i:i + 2]
        return argv
    CASES.append(Case(f"sweep-{_id}", _make, _words))


@case("sweep-experiment-missing", "nope.toml", "not found")
def _(tmp: Path) -> list[str]:
    return ["sweep", str(tmp / "nope.toml"), "--grid", "schedule.gpus=1", "--out", str(tmp / "out")]


@case("sweep-experiment-not-toml", "e.toml", "not valid TOML")
def _(tmp: Path) -> list[str]:
    (tmp / "e.toml").write_text("name = \n")
    return ["sweep", str(tmp / "e.toml"), "--grid", "schedule.gpus=1", "--out", str(tmp / "out")]


@case("sweep-profile-as-experiment", "tc1.toml", "a hardware profile, not an experiment")
def _(tmp: Path) -> list[str]:
    return ["sweep", str(ROOT / "hardware_profiles" / "tc1.toml"), "--grid", "schedule.gpus=1",
            "--out", str(tmp / "out")]


@case("sweep-out-at-a-file", "--out", "not a folder")
def _(tmp: Path) -> list[str]:
    argv = sweep_argv(tmp)
    argv[argv.index("--out") + 1] = str(_file_in_the_way(tmp))
    return argv


@case("sweep-out-under-a-file", "--out", "is a file")
def _(tmp: Path) -> list[str]:
    argv = sweep_argv(tmp)
    argv[argv.index("--out") + 1] = str(_file_in_the_way(tmp) / "sub")
    return argv


# ----- effects a fidelity level has no mechanism for --------------------------------------
FIDELITY_CASES = [
    ("analytic", "+link_sharing", ("link_sharing", "--fidelity analytic")),
    ("analytic", "+host_memory_sharing", ("host_memory_sharing", "--fidelity analytic")),
    ("analytic", "+shared_gpu", ("shared_gpu", "--fidelity analytic")),
    ("analytic", "+busy_wake", ("busy_wake", "--fidelity analytic")),
    ("analytic", "-task_gaps,+link_sharing", ("link_sharing", "--fidelity analytic")),
    ("full", "+shared_executor", ("shared_executor", "cannot be forced on")),
    ("full", "+link_shareing", ("--effects", "did you mean +link_sharing")),
    ("full", "link_sharing", ("--effects", "+name or -name")),
    ("fast", "", ("--fidelity", "invalid choice")),
]
for _i, (_level, _effects, _words) in enumerate(FIDELITY_CASES):
    def _make(tmp: Path, level=_level, effects=_effects) -> list[str]:
        argv = simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp) + ["--fidelity", level]
        return argv + (["--effects", effects] if effects else [])
    CASES.append(Case(f"fidelity-{_level}-{_i}", _make, _words))


# ----- command-line parsing: numbers, nesting, endless files, NULs ------------------------
DEEP_ARRAY = "[" * 5000 + "]" * 5000
DEEP_TABLE = "{a = " * 3000 + "1" + "}" * 3000

SIMULATE_FRAMES = ["\u00b2:5", "\u0661:\u0665", "0:\uff11\uff10", "0:999999999999999999999999999", "0:10000001",
                   "5:5", "5:3", "a:b", "5", ":5", "-1:5", "0x1:5", "1e3:5", "0:" + "9" * 100]
for _i, _frames in enumerate(SIMULATE_FRAMES):
    def _make(tmp: Path, frames=_frames) -> list[str]:
        return simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp) + ["--frames", frames]
    CASES.append(Case(f"cli-simulate-frames-{_i}", _make, ("--frames",)))

CASE_FRAMES = [("99999999999999999999999", "18 digits"), ("\u0661\u0662", "ASCII digits"),
               ("\uff11\uff12", "ASCII digits"), ("\u00b2", "ASCII digits"), ("1", "2..1e+07"), ("0", "2..1e+07"),
               ("-5", "2..1e+07"), ("10000001", "2..1e+07"), ("1e3", "invalid int"), ("x", "invalid int"),
               ("", "invalid int"), (" 12 ", None)]
for _i, (_frames, _words) in enumerate(CASE_FRAMES):
    if _words is None:  # the control below: spaces around digits are a number
        continue
    def _make(tmp: Path, frames=_frames) -> list[str]:
        return ["case", "xr_stereo", "--frames", frames, "--out", str(tmp / "out")]
    CASES.append(Case(f"cli-case-frames-{_i}", _make, ("--frames", _words)))

NUMBER_OPTIONS = [
    (["sweep", SWEEP, "--grid", "schedule.gpus=1", "--workers", "\u0661"], "--workers"),
    (["measure", "--pass", "mesh", "--reps", "\u0663"], "--reps"),
    (["measure", "--pass", "mesh", "--warmup", "\uff12"], "--warmup"),
    (["simulate", SWEEP, "--trace-frames", "\u0663"], "--trace-frames"),
    (["simulate", SWEEP, "--trace-frames", "1" * 40], "--trace-frames"),
    (["validate", SWEEP, "--measured", "m", "--repeats", "\u0661"], "--repeats"),
    (["validate", SWEEP, "--measured", "m", "--run-seconds", "nan"], "--run-seconds"),
    (["validate", SWEEP, "--measured", "m", "--run-seconds", "inf"], "--run-seconds"),
    (["validate", SWEEP, "--measured", "m", "--run-seconds=-infinity"], "--run-seconds"),
    (["validate", SWEEP, "--measured", "m", "--run-seconds", "\u0661.\u0665"], "--run-seconds"),
    (["validate", SWEEP, "--measured", "m", "--run-seconds", "1e999"], "--run-seconds"),
    (["calibrate", "t.csv", "--gpus", "\uff14"], "--gpus"),
    (["bench", "--frames", "\u0665"], "--frames"),
    (["study", "validate", "s.toml", "--held-out"], None),  # placeholder removed below
]
for _i, (_argv, _option) in enumerate(NUMBER_OPTIONS):
    if _option is None:
        continue
    def _make(tmp: Path, argv=_argv) -> list[str]:
        return [*argv, "--out", str(tmp / "out")]
    CASES.append(Case(f"cli-number-{_i}", _make, (_option, "invalid")))


def _text_file(name: str, text: str) -> Callable[[Path], Path]:
    def make(tmp: Path) -> Path:
        (tmp / name).write_text(text)
        return tmp / name
    return make


NESTED_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("experiment-array", lambda tmp: simulate_argv(_text_file("e.toml", f"a = {DEEP_ARRAY}\n")(tmp), tmp),
     ("e.toml", "nested too deeply")),
    ("experiment-table", lambda tmp: simulate_argv(_text_file("e.toml", f"a = {DEEP_TABLE}\n")(tmp), tmp),
     ("e.toml", "nested too deeply")),
    ("profile", lambda tmp: simulate_argv(write_toml(tmp / "e.toml", {**experiment(), "profile": str(
        _text_file("p.toml", f"x = {DEEP_ARRAY}\n")(tmp))}), tmp), ("p.toml", "nested too deeply")),
    ("study", lambda tmp: ["study", "validate", str(_text_file("s.toml", f"x = {DEEP_TABLE}\n")(tmp)),
                           "--out", str(tmp / "out")], ("s.toml", "nested too deeply")),
    ("case", lambda tmp: ["case", str(_text_file("case.toml", f"x = {DEEP_ARRAY}\n")(tmp)),
                          "--out", str(tmp / "out")], ("case.toml", "nested too deeply")),
    ("set-value", lambda tmp: simulate_argv(write_toml(tmp / "e.toml", experiment()), tmp,
                                            f"scene.width={DEEP_ARRAY}"), ("--set", "nested too deeply")),
    ("grid-value", lambda tmp: sweep_argv(tmp, grid=(f"scene.width={DEEP_ARRAY}",)),
     ("--grid scene.width", "nested too deeply")),
    ("calibrate-base", lambda tmp: ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--base",
                                    str(_text_file("b.toml", f"x = {DEEP_ARRAY}\n")(tmp)),
                                    "--out", str(tmp / "out" / "p.toml")], ("b.toml", "nested too deeply")),
]
for _id, _make, _words in NESTED_CASES:
    CASES.append(Case(f"cli-nested-{_id}", _make, _words))

DEV_ZERO_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("simulate", lambda tmp: ["simulate", "/dev/zero", "--out", str(tmp / "out")], ("/dev/zero", "64 MiB")),
    ("sweep", lambda tmp: ["sweep", "/dev/zero", "--grid", "schedule.gpus=1", "--out", str(tmp / "out")],
     ("/dev/zero", "64 MiB")),
    ("study", lambda tmp: ["study", "validate", "/dev/zero", "--out", str(tmp / "out")], ("/dev/zero", "64 MiB")),
    ("profile", lambda tmp: simulate_argv(write_toml(tmp / "e.toml", {**experiment(), "profile": "/dev/zero"}), tmp),
     ("profile", "/dev/zero")),
    ("calibrate", lambda tmp: ["calibrate", "/dev/zero", "--out", str(tmp / "out" / "p.toml")], ("/dev/zero", "not a file")),
    ("calibrate-base", lambda tmp: ["calibrate", str(ROOT / "data/lavapipe/mesh.csv"), "--base", "/dev/zero",
                                    "--out", str(tmp / "out" / "p.toml")], ("/dev/zero", "64 MiB")),
    ("measured", lambda tmp: ["validate", SWEEP, "--measured", "/dev/zero", "--out", str(tmp / "out")],
     ("/dev/zero", "not a folder")),
    ("case", lambda tmp: ["case", "/dev/zero", "--out", str(tmp / "out")], ("/dev/zero", "no case")),
    ("null-experiment", lambda tmp: ["simulate", "/dev/null", "--out", str(tmp / "out")], ("/dev/null", "empty")),
]
for _id, _make, _words in DEV_ZERO_CASES:
    CASES.append(Case(f"cli-devzero-{_id}", _make, _words))

NUL_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("experiment-arg", lambda tmp: ["simulate", "a\0b.toml", "--out", str(tmp / "out")], ("argument 2", "NUL")),
    ("out-arg", lambda tmp: ["simulate", SWEEP, "--out", str(tmp / "out") + "\0x"], ("argument 4", "NUL")),
    ("set-arg", lambda tmp: ["simulate", SWEEP, "--set", "scene.wi\0dth=3", "--out", str(tmp / "out")], ("NUL",)),
    ("grid-arg", lambda tmp: sweep_argv(tmp, grid=("schedule.gpus=1\0",)), ("NUL",)),
    ("study-arg", lambda tmp: ["study", "validate", "s\0.toml", "--out", str(tmp / "out")], ("NUL",)),
    ("experiment-name", lambda tmp: ["simulate", str(write_toml(tmp / "e.toml", {**experiment(), "name": "a\0b"}))],
     ("e.toml", "name", "NUL")),
    ("experiment-name-parent", lambda tmp: ["simulate", str(write_toml(tmp / "e.toml", {**experiment(), "name": "../x"}))],
     ("e.toml", "name", "separator")),
    ("experiment-name-absolute", lambda tmp: ["simulate", str(write_toml(tmp / "e.toml", {**experiment(), "name": "/tmp/x"}))],
     ("e.toml", "name", "separator")),
    ("experiment-name-dotdot", lambda tmp: ["simulate", str(write_toml(tmp / "e.toml", {**experiment(), "name": ".."}))],
     ("e.toml", "name", "'..'")),
    ("profile-path", lambda tmp: simulate_argv(write_toml(tmp / "e.toml", {**experiment(), "profile": "a\0b.toml"}), tmp),
     ("profile", "not found")),
]
for _id, _make, _words in NUL_CASES:
    CASES.append(Case(f"cli-nul-{_id}", _make, _words))


# ----- case files ------------------------------------------------------------------------
def _case(body: str = "", top: str = "", *args: str, name: str = "t") -> Callable[[Path], list[str]]:
    """A one-run case file in the test's folder (as tests/test_cases.py writes them)."""
    def make(tmp: Path) -> list[str]:
        exp = (ROOT / "experiments" / "cases" / "xr_stereo" / "quest3_pcie4.toml").as_posix()
        (tmp / "case.toml").write_text(f'name = "{name}"\ntitle = "t"\n{top}[[runs]]\nname = "a"\n'
                                       f'label = "a"\nexperiment = "{exp}"\n' + body)
        return ["case", str(tmp / "case.toml"), "--out", str(tmp / "out"), *args]
    return make


CASE_CASES: list[tuple[str, Callable[[Path], list[str]], tuple[str, ...]]] = [
    ("name-parent", _case(name="../x"), ("case.toml", "name", "separator")),
    ("name-absolute", _case(name="/tmp/x"), ("name", "separator")),
    ("run-name-parent", lambda tmp: _rename_run(tmp, "../r"), ("runs[0].name", "separator")),
    ("run-name-nul", lambda tmp: _rename_run(tmp, "r\\u0000"), ("runs[0].name", "NUL")),
    ("run-each-slash", _case('each = { "scene.width" = ["64/2"] }\n'), ("runs[0].each", "separator")),
    ("set-number", _case("set = [3]\n"), ("runs[0].set[0]", "KEY=VALUE")),
    ("set-table", _case("set = [{a = 1}]\n"), ("runs[0].set[0]", "KEY=VALUE")),
    ("set-misspelt", _case('set = ["schedule.gpuz=2"]\n'), ("schedule.gpuz", "did you mean 'gpus'")),
    ("derived-metric", _case('[[derived]]\nname = "g"\nlabel = "g"\nkind = "ratio"\nmetric = "fsp"\nruns = ["a", "a"]\n'),
     ("derived[0].metric",)),
    ("column-kind", _case('[[columns]]\nname = "c"\nlabel = "c"\nkind = "utilisation"\nselect = "gpu*"\n'),
     ("columns[0].kind",)),
    ("unknown-top", _case(top="colums = 1\n"), ("colums", "unknown key")),
    ("frames-one", _case("", "", "--frames", "1"), ("--frames", "2..1e+07")),
    ("frames-huge", _case("", "", "--frames", "100000000"), ("--frames", "1e+07")),
    ("no-case", lambda tmp: ["case", "nope", "--out", str(tmp / "out")], ("no case of that name",)),
]


def _rename_run(tmp: Path, name: str) -> list[str]:
    argv = _case()(tmp)
    path = tmp / "case.toml"
    path.write_text(path.read_text().replace('[[runs]]\nname = "a"', f'[[runs]]\nname = "{name}"'))
    return argv


for _id, _make, _words in CASE_CASES:
    CASES.append(Case(f"case-{_id}", _make, _words))


# ----- hardware what-ifs (profile.* overrides) on simulate, sweep and study --------------------
WHATIF_CASES = [
    ("profile.gpus.0.speed=0", ("gpus[0].speed", "> 0")),
    ("profile.gpus.*.speed=-2", ("gpus[0].speed",)),
    ("profile.gpus.0.physical=99", ("gpus[0].physical",)),
    ("profile.gpus.*.link.h2d_gbps=0", ("gpus[0].link.h2d_gbps", "> 0")),
    ("profile.host.memcpy_threads=0", ("host.memcpy_threads", ">= 1")),
    ("profile.host.dispatch_ns=-1", ("host.dispatch_ns", ">= 0")),
    ("profile.host.dispatch_ns=1e30", ("host.dispatch_ns",)),
    ("profile.gpu_count=1000", ("gpu_count", "<= 64")),
    ("profile.peer_mesh.bandwidth_gbps=-1", ("peer_mesh",)),
    ("profile.gpus.0.costs.mesh.ns_per_triangle=nan", ("ns_per_triangle", "finite")),
    ("profile.gpus.0.queues.graphics=0", ("gpus[0].queues.graphics",)),
    ("profile.hst.dispatch_ns=1", ("did you mean 'host'",)),
]
for _i, (_set, _words) in enumerate(WHATIF_CASES):
    CASES.append(Case(f"whatif-simulate-{_i}", lambda tmp, s=_set: simulate_argv(
        write_toml(tmp / "e.toml", experiment()), tmp, s), _words))
for _i, (_set, _words) in enumerate(WHATIF_CASES[:6]):
    key, _, value = _set.partition("=")
    CASES.append(Case(f"whatif-sweep-{_i}", lambda tmp, k=key, v=value: sweep_argv(tmp, grid=(f"{k}={v}",)),
                      (f"--grid {key}", "no value", *_words)))
for _i, (_set, _words) in enumerate(WHATIF_CASES[:4]):
    CASES.append(Case(f"whatif-study-{_i}", _mini(lambda d, s=_set: d["calibration"]["config"][0]["set"].append(s)),
                      ("s.toml", "calibration.config[0]", *_words)))


# ----- the test --------------------------------------------------------------------------
def test_there_are_enough_cases():
    assert len(CASES) >= 150
    assert len({c.id for c in CASES}) == len(CASES)


@pytest.mark.parametrize("bad", CASES, ids=lambda c: c.id)
def test_bad_input_is_one_line_exit_2(bad: Case, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a default out/ folder would land here
    argv = bad.make(tmp_path)
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse errors exit from the parser
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for words in bad.expect:
        assert words in lines[0], (words, lines[0])
    assert not (tmp_path / "out").exists()  # nothing half-written
    assert not [p for p in tmp_path.rglob("*.tmp")]


def test_the_mini_study_loads_and_is_refused_for_want_of_runs(tmp_path: Path, capsys, monkeypatch):
    """The positive control of the study cases: the unbroken study loads, and with no runs
    measured yet it is refused saying where runs were looked for and how to measure them
    (not the bad input of a broken study file: the file's error would name the file)."""
    monkeypatch.chdir(tmp_path)
    assert main(_mini(lambda d: None)(tmp_path) + ["--held-out"]) == 2
    err = capsys.readouterr().err
    assert "no such runs folder" in err and "mgpusim study measure" in err and "s.toml" not in err
    assert not (tmp_path / "out" / "report.md").exists()


def test_a_matching_measured_run_validates(tmp_path: Path, capsys, monkeypatch):
    """The positive control of the measured-folder cases: the same folder, unedited, passes."""
    monkeypatch.chdir(tmp_path)
    folder = measured_folder(tmp_path)
    assert main(validate_argv(tmp_path, folder)) == 0
    assert (tmp_path / "out" / "summary.json").is_file()


def test_a_measured_run_recorded_before_inputs_is_compared_on_the_basics(tmp_path: Path, monkeypatch):
    """Runs saved before the full inputs were recorded still validate (their recorded keys
    match); a basic key that differs is still refused."""
    monkeypatch.chdir(tmp_path)
    folder = measured_folder(tmp_path)
    summary = json.loads((folder / "summary.json").read_text())
    del summary["config"]["inputs"]
    (folder / "summary.json").write_text(json.dumps(summary))
    assert main(validate_argv(tmp_path, folder, "scene.passes.0.iterations=4000")) == 0
    assert main(validate_argv(tmp_path, folder, "schedule.host_copy=false")) == 2


def test_simulated_time_past_int64_is_an_input_error():
    """The last guard behind the bound on one task's time: a clock passing 2^63 ns (here with
    a cost model that skips that bound) stops with an InputError, not an OverflowError."""
    class Unbounded(CostModel):
        def pass_ns(self, device, kind, work):
            return 2 ** 62

    q = QueueRef(0, "graphics")
    tasks = (PassTask("present", "present", q, "present", {}, (Dep("present", -1),)),)
    program = FrameProgram("long", 1, 4, 0, (tasks,))
    engine = Engine(program, Unbounded(parse_profile(profile_dict(), "p.toml")))
    with pytest.raises(InputError, match="int64"):
        engine.run()


# ----- a sweep's folder holding a point file this code did not write ----------------------
POINT_FILES: list[tuple[str, bytes, str]] = [
    ("list", b"[1, 2]", "JSON list"),
    ("string", b'"text"', "JSON str"),
    ("number", b"5", "JSON int"),
    ("null", b"null", "JSON NoneType"),
    ("empty-object", b"{}", "'summary'"),
    ("summary-list", b'{"summary": [], "error": null, "wall_s": 1}', "'summary'"),
    ("error-number", b'{"summary": {}, "error": 5, "wall_s": 1}', "'error'"),
    ("wall-text", b'{"summary": {}, "error": null, "wall_s": "1"}', "'wall_s'"),
    ("wall-bool", b'{"summary": {}, "error": null, "wall_s": true}', "'wall_s'"),
    ("no-wall", b'{"summary": {}, "error": null}', "'wall_s'"),
    ("not-json", b"{oops", "not valid JSON"),
    ("empty", b"", "not valid JSON"),
    ("binary", b"\xff\xfe\x00", "cannot read"),
    ("deep", b"[" * 100_000 + b"]" * 100_000, "not valid JSON"),
]


@pytest.fixture(scope="module")
def finished_sweep(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "out"
    assert main(sweep_argv(out.parent, "--set", "schedule.frames=20")) == 0
    return out


@pytest.mark.parametrize("name, content, words", POINT_FILES, ids=[p[0] for p in POINT_FILES])
def test_a_point_file_of_another_shape_is_refused_naming_it(finished_sweep: Path, tmp_path: Path, capsys,
                                                           name: str, content: bytes, words: str):
    """Valid JSON of the wrong shape (or not JSON) in points/, named as one of the sweep's
    points (as sweeps before 2026-12 saved each point, and still read): one line naming the
    file and what is wrong, exit 2; the file is left for its owner and the table is not
    rewritten."""
    import shutil
    out = tmp_path / "out"
    shutil.copytree(finished_sweep, out)
    (saved,) = (out / "points").glob("single-*.parquet")  # the points run one by one, saved together
    point = out / "points" / f"{pd.read_parquet(saved)['id'][0]}.json"
    point.write_bytes(content)
    table = (out / "sweep.parquet").read_bytes()
    capsys.readouterr()
    assert main(sweep_argv(tmp_path, "--set", "schedule.frames=20")) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and point.name in lines[0] and words in lines[0], lines
    assert "delete it" in lines[0] and "Traceback" not in lines[0]
    assert point.read_bytes() == content and (out / "sweep.parquet").read_bytes() == table


def test_a_metric_no_point_has_is_refused_once_the_points_ran_and_they_are_kept(tmp_path: Path, capsys):
    """utilization.gpu9.graphics can only be looked for in the table: refused (one line, the
    closest column named) before sweep.parquet is written; the rerun with the right metric
    runs no point again."""
    argv = sweep_argv(tmp_path, "--set", "schedule.frames=20")
    assert main([*argv, "--metric", "utilization.gpu9.graphics"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "did you mean 'utilization.gpu1.graphics'" in lines[0]
    saved = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out" / "points").iterdir()}
    rows = sum(len(pd.read_parquet(p)) for p in (tmp_path / "out" / "points").glob("single-*.parquet"))
    assert rows == 2 and not (tmp_path / "out" / "sweep.parquet").exists()
    assert main([*argv, "--metric", "utilization.gpu1.graphics"]) == 0
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out" / "points").iterdir()} == saved


# ----- a run that fails while writing leaves no folder -------------------------------------
@pytest.mark.parametrize("fails", ["write_links", "timeline_png", "write_trace"])
@pytest.mark.parametrize("error", [MemoryError, OSError, KeyboardInterrupt])
def test_a_run_failing_while_writing_leaves_no_partial_folder(tmp_path: Path, monkeypatch, capsys,
                                                            fails: str, error: type):
    """The folder is written beside --out and moved in at the end: out of memory, a full disk
    or Ctrl-C in the middle leaves neither --out nor its new parent folders nor a temporary."""
    from mgpusim.io import writers as output

    def boom(*args, **kwargs):
        raise error(28, "No space left on device") if error is OSError else error()
    monkeypatch.setattr(output, fails, boom)
    code = main(["simulate", SWEEP, "--set", "schedule.frames=20", "--out", str(tmp_path / "new" / "out")])
    assert code == {MemoryError: 1, OSError: 2, KeyboardInterrupt: 130}[error]
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_a_rerun_into_an_existing_folder_replaces_its_files_and_keeps_the_others(tmp_path: Path, monkeypatch):
    from mgpusim.io import writers as output
    out = tmp_path / "out"
    assert main(["simulate", SWEEP, "--set", "schedule.frames=20", "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    before = (out / "summary.json").read_text()
    monkeypatch.setattr(output, "write_links", lambda *a, **k: (_ for _ in ()).throw(MemoryError()))
    assert main(["simulate", SWEEP, "--set", "schedule.frames=30", "--out", str(out)]) == 1
    assert (out / "summary.json").read_text() == before  # the failed run changed nothing
    monkeypatch.undo()
    assert main(["simulate", SWEEP, "--set", "schedule.frames=30", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["frames"] == 30
    assert (out / "notes.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]
