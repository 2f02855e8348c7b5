"""Calibration: fit a hardware profile's coefficients to `mgpusim measure` tables."""
from mgpusim.calibration.fit import Fit, fit_nonnegative
from mgpusim.calibration.pass_fit import Calibration, calibrate, read_measurements
from mgpusim.calibration.profile_out import apply, lavapipe_base, report

__all__ = ["Calibration", "Fit", "apply", "calibrate", "fit_nonnegative", "lavapipe_base",
           "read_measurements", "report"]
