"""PhySynth: physics-based synthetic UWB ranging + IMU + availability + AoI traces.

The names most scripts need are available here (imported on first use, so ``import physynth`` stays
fast)::

    import physynth

    scn = physynth.load_scenario("cablecar-descending")
    for trace in physynth.generate_traces(scn, n=10, seed=1):
        ...
    physynth.compute_metrics(physynth.read_dataset("runs/default").traces)
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_RECORDS = ("Anchors", "Imu", "Reason", "Trace", "Truth", "Uwb")
_LAZY = {
    **{name: "physynth.records" for name in _RECORDS},
    "Scenario": "physynth.scenario",
    "scenario_from_dict": "physynth.scenario",
    "scenario_to_dict": "physynth.scenario",
    "load_scenario": "physynth.io.scenario_file",
    "save_scenario": "physynth.io.scenario_file",
    "list_presets": "physynth.io.scenario_file",
    "compile_scenario": "physynth.generate",
    "generate_trace": "physynth.workflows",  # physynth.generate's, on a preset name, file or mapping too
    "generate_traces": "physynth.workflows",
    "compute_metrics": "physynth.evaluate.metrics",
    "read_dataset": "physynth.io.dataset",
    "iter_traces": "physynth.io.dataset",
    "write_dataset": "physynth.io.dataset",
    "generate_dataset": "physynth.workflows",
    "calibrate_datasets": "physynth.workflows",
    "validate_datasets": "physynth.workflows",
}


def __getattr__(name: str) -> Any:
    """Imported on first use, so ``import physynth`` (and ``physynth --help``) does not pay for NumPy."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'physynth' has no attribute {name!r}")


__all__ = ["__version__", *_LAZY]
