"""Calibration: real (or synthetic) traces -> a Scenario whose generator reproduces them, plus a fit
report (DESIGN.md section 2, paper sections III.C-G).

Each model has its own fit returning a :class:`Fit` (fitted parameters, sample count, diagnostics):

- :func:`fit_path`: path geometry over arc length (degree-10 polynomial or waypoint spline)
- :func:`fit_motion`: speed profile, cruise speed, dwells, run-to-run spread
- :func:`transfer_scenario`: a scenario moved onto the geometry, motion and anchors of real runs
"""

from ._base import CalibrationError, Fit
from .geometry import anchor_layout, fit_motion, fit_path, fit_path_perturbation, transfer_scenario

__all__ = [
    "CalibrationError",
    "Fit",
    "anchor_layout",
    "fit_motion",
    "fit_path",
    "fit_path_perturbation",
    "transfer_scenario",
]
