"""Optional extras: the one place that imports an optional dependency and, when it is missing, says which
extra of PhySynth installs it (``pip install 'physynth[ml]'``).

The core install is light (numpy, scipy, pandas, pyarrow, pydantic, typer, rich); the heavy parts are
extras: ``report`` (matplotlib), ``scale`` (Dask), ``export`` (h5py, rosbags, mcap), ``ml`` (PyTorch).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import PhySynthError


def install_hint(extra: str) -> str:
    """How to install ``extra``: from PyPI, or into a clone."""
    return f"pip install 'physynth[{extra}]', or pip install -e '.[{extra}]' in a PhySynth clone"


def require(module: str, extra: str, what: str, *, otherwise: str = "") -> ModuleType:
    """The module ``module``, or a one-line :class:`~physynth.errors.PhySynthError`: ``what`` needs it,
    the extra that installs it, and ``otherwise`` (what to do without it) when given."""
    try:
        return importlib.import_module(module)
    except ImportError:
        tail = f" or {otherwise}" if otherwise else ""
        raise PhySynthError(f"{what} needs {module.split('.')[0]}, which is not installed: install the extra "
                            f"physynth[{extra}] ({install_hint(extra)}){tail}") from None
