"""Datasets on disk, scenario files, importers of real recordings, exports.

The dataset names are imported on first use, so commands that only read scenario files do not pay for
pyarrow.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Dataset", "DatasetWriter", "iter_traces", "read_dataset", "read_meta", "write_dataset"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from . import dataset

        return getattr(dataset, name)
    raise AttributeError(f"module 'physynth.io' has no attribute {name!r}")
