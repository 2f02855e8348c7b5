"""Calibration: fit a hardware profile's coefficients to `mgpusim measure` tables."""
from .fit import Fit, fit_nonnegative
from .model import Calibration, calibrate, read_measurements
from .profile_out import apply, lavapipe_base, report

__all__ = ["Calibration", "Fit", "apply", "calibrate", "fit_nonnegative", "lavapipe_base",
           "read_measurements", "report"]
