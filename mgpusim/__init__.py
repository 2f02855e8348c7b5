"""mgpusim: predict how a rendering workload behaves on several GPUs.

Python API::

    import mgpusim
    exp = mgpusim.load_experiment("experiments/sort_first_tc1.toml", overrides={"schedule.gpus": 3})
    result = mgpusim.simulate(exp)
    result.summary["frame_time_ms"], result.trace, result.frames
"""
from .errors import InputError, MgpusimError, ScheduleError
from .experiment import Experiment, load_experiment
from .profile import HardwareProfile, load_profile
from .results import Result
from .simulate import simulate

__all__ = ["Experiment", "HardwareProfile", "InputError", "MgpusimError", "Result", "ScheduleError",
           "load_experiment", "load_profile", "simulate"]
__version__ = "0.1.0"
