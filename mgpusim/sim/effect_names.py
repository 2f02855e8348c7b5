"""The names of the fidelity levels and of the effects, without the model behind them.

What a command line needs to offer them as choices (`mgpusim simulate --fidelity`, `--effects`)
without importing the effects' tests, the cost model, numpy or SimPy: :mod:`.effects` takes
its levels from here, and a test checks that its effects are these, in this order.
"""
from __future__ import annotations

#: The fidelity levels, cheapest first (docs/fidelity.md).
FIDELITIES: tuple[str, ...] = ("analytic", "queues", "full")

#: The effects of :data:`mgpusim.sim.effects.EFFECTS`, in its order.
EFFECT_NAMES: tuple[str, ...] = (
    "link_sharing", "host_pcie", "copy_engine_caps", "host_memory_sharing", "shared_executor",
    "shared_gpu", "host_submission", "busy_wake", "host_frame_work", "uncached_reads", "task_gaps",
    "memory_capacity")
