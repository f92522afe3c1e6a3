"""Physical ranges of every scenario field and the size budget of a generation (docs/reliability.md).

:data:`BOUNDS` and :func:`check_bounds` (the range of every scenario number, checked whenever a scenario
is built) live in :mod:`physynth.field_bounds`, below :mod:`physynth.scenario`, and are re-exported here.

:func:`estimate_size` predicts, before any work, the samples, peak memory and output size of
generating ``n`` traces; :func:`check_budget` refuses a generation over :data:`MEMORY_BUDGET_BYTES`
or :data:`OUTPUT_BUDGET_BYTES` with the estimate in the message (``force=True`` overrides), and a
scenario whose trip is too short to give a trace at all.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .constants import IMU_BODY_FRAME, IMU_FRAME
from .errors import BudgetError, ScenarioError
from .field_bounds import BOUNDS, Bound, check_bounds  # noqa: F401  (re-exported)

if TYPE_CHECKING:
    from .scenario import Scenario


def _gb_env(name: str, default_gb: float) -> float:
    try:
        return float(os.environ.get(name, "")) * 1e9
    except ValueError:
        return default_gb * 1e9


MEMORY_BUDGET_BYTES = _gb_env("PHYSYNTH_MEMORY_BUDGET_GB", 4.0)
"""Peak memory a generation may need [bytes]: 4 GB, or ``PHYSYNTH_MEMORY_BUDGET_GB``."""
OUTPUT_BUDGET_BYTES = _gb_env("PHYSYNTH_OUTPUT_BUDGET_GB", 20.0)
"""Size a generated dataset may reach [bytes]: 20 GB, or ``PHYSYNTH_OUTPUT_BUDGET_GB``."""
MIN_TRUTH_SAMPLES = 10
"""A trace shorter than this many truth samples is refused (a zero-length path, an absurd speed)."""

# bytes per sample: about twice the peak tracemalloc measures on the cablecar preset (3.9 MB per trace)
_WORK_BYTES = {"truth": 150, "imu": 80, "uwb": 100}
_TABLE_BYTES = {"truth": 64, "imu": 40, "uwb": 60}
ROW_GROUP_TRACES = 16
"""Traces per Parquet row group of a generated dataset (``io.shards`` writes them so; the budget holds one)."""
# bytes per row on disk, as the Parquet writer stores them: measured 36-44 B per truth row, 12-13 B per IMU
# row and triad (ENU, body accelerometer, body gyroscope), 18-21 B per UWB row (cablecar-descending,
# walk-hanyang, handheld-broad), 8-30 % under these; the estimate also takes the longest trip the spreads
# allow (tests/test_budget_estimate.py keeps it above what is written and within twice of it)
_DISK_BYTES = {"truth": 48, "imu_triad": 16, "uwb": 24}


@dataclass(frozen=True, slots=True)
class SizeEstimate:
    """Predicted size of generating ``n_traces`` traces (upper bounds over the per-run spreads)."""

    n_traces: int
    duration_s: float
    min_trip_s: float
    truth_samples: int
    imu_samples: int
    uwb_rows: int
    peak_memory_bytes: float
    output_bytes: float  # on disk, as the Parquet writer stores the traces
    sample_bytes: float = 0.0  # the traces' tables in memory: what generating and reducing them handles
    processes: int = 1  # processes generating at once on this machine, each holding its own traces

    def describe(self) -> str:
        over = f" over {self.processes} processes" if self.processes > 1 else ""
        return (f"{self.n_traces} trace(s) of up to {self.duration_s:.4g} s: {self.truth_samples:,} truth, "
                f"{self.imu_samples:,} IMU and {self.uwb_rows:,} UWB rows per trace, up to about "
                f"{self.peak_memory_bytes / 1e9:.3g} GB of memory{over} and {self.output_bytes / 1e9:.3g} GB on disk")


def estimate_size(scn: Scenario, n_traces: int, processes: int = 1) -> SizeEstimate:
    """Samples, peak memory and output size of ``n_traces`` traces of ``scn``, before any work.

    ``processes`` generate at once on this machine (worker processes), each holding its own traces: the
    peak memory is theirs together, for the run as a whole."""
    from .models.motion import compile_speed_shape
    from .models.path import compile_path

    try:
        length = float(scn.path.length_m) if scn.path.kind == "polynomial" else compile_path(scn.path).length_m
        shape_mean = compile_speed_shape(scn.motion.profile).mean
        if scn.variation is not None and scn.variation.random_route_prob > 0:
            length = max(length, _random_route_bound_m(scn))
    except (ValueError, ArithmeticError) as exc:
        raise ScenarioError(f"scenario '{scn.name}': {exc}") from None
    m = scn.motion
    trip_min, trip_max = trip_range_s(scn, length, shape_mean)
    duration = m.dwell_start_s + trip_max + m.dwell_end_s
    truth = math.floor(duration * scn.truth_rate_hz) + 1
    imu = math.floor(duration * scn.imu.rate_hz) + 1
    n_anchors = len(scn.anchors)
    if scn.variation is not None and scn.variation.layout_distribution is not None:  # drawn layouts: the largest
        n_anchors = max(n_anchors, scn.variation.layout_distribution.anchor_count[1])
    uwb = math.ceil(duration * scn.uwb.burst_rate_hz * (1 + 1e-3)) * n_anchors
    counts = {"truth": truth, "imu": imu, "uwb": uwb}
    work = sum(_WORK_BYTES[k] * v for k, v in counts.items())
    table = sum(_TABLE_BYTES[k] * v for k, v in counts.items())
    triads = (IMU_FRAME in scn.imu_frames) + 2 * (IMU_BODY_FRAME in scn.imu_frames)
    disk = _DISK_BYTES["truth"] * truth + _DISK_BYTES["imu_triad"] * triads * imu + _DISK_BYTES["uwb"] * uwb
    return SizeEstimate(n_traces=n_traces, duration_s=duration, min_trip_s=trip_min, truth_samples=truth,
                        imu_samples=imu, uwb_rows=uwb,
                        peak_memory_bytes=max(1, processes) * (work + min(n_traces, ROW_GROUP_TRACES) * table),
                        output_bytes=n_traces * disk, sample_bytes=n_traces * table, processes=max(1, processes))


def _random_route_bound_m(scn: Scenario) -> float:
    """Upper bound of the length of the scenario's random routes [m] (``variation``), with 20 % for the
    smooth path through the waypoints being longer than their polyline."""
    import numpy as np

    from .models.path import compile_path
    from .models.variation import max_route_length_m

    geo = compile_path(scn.path)
    pts = np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, 200))[0], dtype=float)
    centre = np.mean([a.pos_enu_m for a in scn.anchors], axis=0) if scn.anchors else pts.mean(axis=0)
    return 1.2 * max_route_length_m(scn.variation, pts, np.asarray(centre, dtype=float))


def trip_range_s(scn: Scenario, length_m: float, shape_mean: float) -> tuple[float, float]:
    """(shortest, longest) trip [s] of the scenario's runs over a path of ``length_m`` whose speed profile
    has mean ``shape_mean`` (the spreads of cruise speed and length at their extremes)."""
    m = scn.motion
    v_hi = m.cruise_speed_mps * (1 + m.cruise_speed_spread_frac)
    v_lo = m.cruise_speed_mps * (1 - m.cruise_speed_spread_frac)
    return (length_m * (1 - m.length_spread_frac) / (v_hi * shape_mean),
            length_m * (1 + m.length_spread_frac) / (v_lo * shape_mean))


def check_trip(scn: Scenario, est: SizeEstimate | None = None, *, min_trip_s: float | None = None) -> None:
    """Refuse a scenario whose shortest trip is too short to make traces (every generation path checks
    it: :func:`check_budget`, :func:`physynth.generate.compile_scenario`). The shortest trip comes from
    ``min_trip_s`` (compile_scenario's, from its compiled path and speed profile), else ``est``, else a
    size estimate of one trace.

    Raises
    ------
    ScenarioError
        The shortest trip gives fewer than :data:`MIN_TRUTH_SAMPLES` truth samples (not overridable).
    """
    if min_trip_s is None:
        min_trip_s = (estimate_size(scn, 1) if est is None else est).min_trip_s
    moving = min_trip_s * scn.truth_rate_hz
    if not moving >= MIN_TRUTH_SAMPLES:
        raise ScenarioError(f"scenario '{scn.name}': the trip takes only {min_trip_s:.3g} s "
                            f"({moving:.3g} truth samples at {scn.truth_rate_hz:g} Hz, fewer than "
                            f"{MIN_TRUTH_SAMPLES}): check path length and cruise speed")


def check_budget(scn: Scenario, n_traces: int, *, force: bool = False, writes: bool = True,
                 processes: int = 1) -> SizeEstimate:
    """Refuse, before any work, a generation that is too short to make traces or over budget.

    ``processes``: worker processes generating at once on this machine; the memory budget holds for
    them together (the run as a whole), not for each (:func:`estimate_size`).

    ``writes``: the traces are written (a dataset: their size on disk is held against the output budget);
    False for work that only reduces them (the studies: their samples in memory, a bound on the time).

    Raises
    ------
    ScenarioError
        The shortest trip gives fewer than :data:`MIN_TRUTH_SAMPLES` truth samples (:func:`check_trip`).
    BudgetError
        Unless ``force``: the peak memory or the output size exceeds its budget; the message holds
        the estimate.
    """
    est = estimate_size(scn, n_traces, processes)
    check_trip(scn, est)
    if force:
        return est
    if est.peak_memory_bytes > MEMORY_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.describe()}; the memory budget is "
                          f"{MEMORY_BUDGET_BYTES / 1e9:.3g} GB (PHYSYNTH_MEMORY_BUDGET_GB)")
    if writes and est.output_bytes > OUTPUT_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.describe()}; the output budget is "
                          f"{OUTPUT_BUDGET_BYTES / 1e9:.3g} GB (PHYSYNTH_OUTPUT_BUDGET_GB)")
    if not writes and est.sample_bytes > OUTPUT_BUDGET_BYTES:
        raise BudgetError(f"scenario '{scn.name}': {est.n_traces} trace(s) of up to {est.duration_s:.4g} s are "
                          f"about {est.sample_bytes / 1e9:.3g} GB of samples to generate and reduce (nothing is "
                          f"written, but it would take long); the output budget is {OUTPUT_BUDGET_BYTES / 1e9:.3g} GB "
                          "(PHYSYNTH_OUTPUT_BUDGET_GB)")
    return est
