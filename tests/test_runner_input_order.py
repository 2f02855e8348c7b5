"""The order a runner submit thread checks a task's inputs in (no Vulkan needed: the nodes are
built on stand-in works that carry only what the plan reads)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from mgpusim.model.tasks import HostCopyTask
from mgpusim.real.runner.plan import build_nodes
from mgpusim.real.runner.work import GpuWork, HostWork
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.program import build_program

XR = Path(__file__).resolve().parents[1] / "experiments" / "lavapipe" / "xr.toml"


def _stand_in_works(program):
    """Per phase, task name -> a GpuWork / HostWork with the device and queue the plan reads."""
    def work(task):
        if isinstance(task, HostCopyTask):
            return HostWork(task, None, 1)
        queue = SimpleNamespace(family=SimpleNamespace(index=task.queue.index))
        return GpuWork(task, task.queue.device, None, queue, task.queue.engine, None, 0, False, 1)
    return [{t.name: work(t) for t in tasks} for tasks in program.templates]


def test_inputs_from_other_queues_are_checked_earliest_first():
    program = build_program(load_experiment(XR, {"schedule.scaling": "strong"}))
    nodes = build_nodes(program, _stand_in_works(program), 6)
    renders = [n for n in nodes if n.task.name == "render1.tori" and n.frame >= 2]
    assert renders
    for node in renders:
        host = [(prod.frame, prod.index, prod.task.name) for prod, kind in node.deps if kind == "host"]
        assert host == sorted(host), host
        # the present and acquire of two frames back come before the last frame's render on
        # GPU 0, which ends last: after its fence nothing is left to check
        names = [name for _f, _i, name in host]
        assert names[-1] == "render0.tori" and {"present", "acquire"} <= set(names[:-1])
