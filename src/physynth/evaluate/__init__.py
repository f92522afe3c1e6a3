"""Evaluation shared by validation, calibration and the command line.

:mod:`~physynth.evaluate.grid` (the 100 Hz grid, fresh mask, AoI), :mod:`~physynth.evaluate.metrics`
(every metric of the paper's section 5, written once) and :mod:`~physynth.evaluate.stats` (Allan
deviation, KS, Wasserstein-1, Anderson-Darling).
"""
