"""mgpusim: predict how a rendering workload behaves on several GPUs.

Python API::

    import mgpusim
    exp = mgpusim.load_experiment("experiments/sort_first_tc1.toml", overrides={"schedule.gpus": 3})
    result = mgpusim.simulate(exp)
    result.summary["frame_time_ms"], result.trace, result.frames
    table = mgpusim.sweep("experiments/sort_first_tc1.toml", {"schedule.gpus": [1, 2, 3]}, out="out/sweep")
"""
from mgpusim.model.errors import InputError, MgpusimError, ScheduleError
from mgpusim.model.profile import HardwareProfile, load_profile
from mgpusim.results.summary import Result
from mgpusim.schedules.experiment import Experiment, load_experiment
from mgpusim.sim.simulation import simulate
from mgpusim.studies.sweep_grid import sweep

__all__ = ["Experiment", "HardwareProfile", "InputError", "MgpusimError", "Result", "ScheduleError",
           "load_experiment", "load_profile", "simulate", "sweep"]
__version__ = "0.1.0"
