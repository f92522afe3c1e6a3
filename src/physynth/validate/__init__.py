"""Validation: real against synthetic traces. :mod:`~physynth.validate.evidence` reduces each side trace
by trace, :mod:`~physynth.validate.compare` builds the report (its record,
:class:`~physynth.validate.report_model.ValidationReport`, lives in :mod:`~physynth.validate.report_model`),
:mod:`~physynth.validate.tables`, :mod:`~physynth.validate.figures` and :mod:`~physynth.validate.render`
turn it into files, and :mod:`~physynth.validate.imu_report` handles IMU-only recordings (the IMU error
statistics both kinds of report hold are :mod:`~physynth.validate.imu_errors`). Reading datasets and
generating the synthetic side is :func:`physynth.workflows.validate_datasets`.
"""

from .compare import EXTENDED_STATISTICS, ValidationReport, compare, read_report

__all__ = ["EXTENDED_STATISTICS", "ValidationReport", "compare", "read_report"]
