"""Validation: real against synthetic traces (:mod:`~physynth.validate.compare`) and the report files
(:mod:`~physynth.validate.render`). Reading datasets and generating the synthetic side is
:func:`physynth.workflows.validate_datasets`.
"""

from .compare import EXTENDED_STATISTICS, ValidationReport, compare, read_report

__all__ = ["EXTENDED_STATISTICS", "ValidationReport", "compare", "read_report"]
