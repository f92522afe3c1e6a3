"""Calibration: real (or synthetic) traces -> a Scenario whose generator reproduces them, plus a fit
report (paper sections III.C-G). Reading datasets for it is
:func:`physynth.workflows.calibrate_datasets`.

Each model has its own fit returning a :class:`Fit` (fitted parameters, sample count, diagnostics):

- :func:`fit_path`: path geometry over arc length (degree-10 polynomial or waypoint spline)
- :func:`fit_motion`: speed profile, cruise speed, dwells, run-to-run spread
- :func:`fit_time_offset`, :func:`fit_burst_schedule`: UWB stamp lag and burst timing
- :func:`select_mixture`: per-anchor LOS regression + NLOS Gaussian mixture chosen by BIC
- :func:`fit_availability`: link range, dropout, outages (exact HMM likelihood), tag outages
- :func:`fit_static_range_bias`: range-proportional bias from static sweeps
- :func:`calibrate`: everything at once -> :class:`CalibrationResult`
- :func:`transfer_scenario`: a scenario moved onto the geometry, motion and anchors of real runs
"""

from ._base import CalibrationError, Fit
from .availability_fit import fit_availability
from .geometry import anchor_layout, fit_motion, fit_path, fit_path_perturbation, transfer_scenario
from .pipeline import calibrate
from .report import CalibrationResult
from .static_bias import fit_static_range_bias
from .uwb_fit import corrected_residuals, fit_burst_schedule, fit_time_offset, select_mixture

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "Fit",
    "anchor_layout",
    "calibrate",
    "corrected_residuals",
    "fit_availability",
    "fit_burst_schedule",
    "fit_motion",
    "fit_path",
    "fit_path_perturbation",
    "fit_static_range_bias",
    "fit_time_offset",
    "select_mixture",
    "transfer_scenario",
]
