"""Trackers trained and scored on PhySynth data (paper section V, Table IV).

- :mod:`physynth.track.inputs`: model inputs on the 100 Hz grid, one function for real and synthetic
  traces (latest range, fresh flag, AoI and position of each anchor; IMU bin mean; truth), relative
  to a per-trace reference point (the anchor centroid).
- :mod:`physynth.track.trackers`: ``aoi-fusion``, ``bilstm`` (PyTorch), ``ls`` and ``ekf`` (NumPy/SciPy)
  behind one small interface (``fit`` on inputs, ``predict`` a position per grid step).
- :mod:`physynth.track.torch_data`: map-style ``torch.utils.data.Dataset`` s over stored traces and over
  traces generated on the fly from their own seeds.
- :mod:`physynth.track.reference`: the Hanyang dataset authors' own estimates (``LS.csv``, ``ESKF.csv``).
- :mod:`physynth.track.scoring`: the position-error statistics of Table IV.

Importing this package does not import torch; the modules that need it say which extra to install.
"""

from typing import Any


def require_torch() -> Any:
    """The torch module, or :class:`~physynth.errors.PhySynthError` naming the extra to install."""
    from ..extras import require

    return require("torch", "ml", "a learned tracker")
