"""Session set-up shared by every test file."""

from __future__ import annotations

import os

# One BLAS thread per process, as the command line runs (src/physynth/cli/__init__.py sets
# OPENBLAS_NUM_THREADS=1 before NumPy loads; docs/scale.md, "BLAS threads"). Set here, before any test module
# imports NumPy, and inherited by the pytest-xdist workers and the subprocesses the tests start: with two
# workers on two cores, each worker's second BLAS thread only spins against the other worker (a calibration
# took 1.5-2x its single-thread time that way). A value set by the user is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
