"""mgpusim: predict how a rendering workload behaves on several GPUs.

Python API::

    import mgpusim
    exp = mgpusim.load_experiment("experiments/sort_first_tc1.toml", overrides={"schedule.gpus": 3})
    result = mgpusim.simulate(exp)
    result.summary["frame_time_ms"], result.trace, result.frames
    table = mgpusim.sweep("experiments/sort_first_tc1.toml", {"schedule.gpus": [1, 2, 3]}, out="out/sweep")
"""
from .errors import InputError, MgpusimError, ScheduleError
from .experiment import Experiment, load_experiment
from .profile import HardwareProfile, load_profile
from .results import Result
from .simulate import simulate
from .sweeps import sweep

__all__ = ["Experiment", "HardwareProfile", "InputError", "MgpusimError", "Result", "ScheduleError",
           "load_experiment", "load_profile", "simulate", "sweep"]
__version__ = "0.1.0"
