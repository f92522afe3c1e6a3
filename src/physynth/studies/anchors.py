"""The anchor deployment study (paper section IV.B, Table III, Figure 6): anchor count x channel regime.

For each regime (:mod:`physynth.studies.regimes`) and each anchor count k, the study generates ``n``
traces and compares them with a reference by the fidelity score S = d_avail + d_med/10 + d_P95/20 and
the >= 1 / >= 2 availability fractions:

- the reference is the real dataset when one is given (pooled over all its anchors, whatever k: the
  paper compares every layout with the full real deployment), otherwise a reference run of the
  scenario as given (``nominal``, every anchor; trace indices n .. 2n-1 of the same root seed, so it
  shares no random numbers with the cells);
- anchors are added in decreasing order of availability (per-anchor fresh fraction on the 100 Hz grid)
  measured on the real dataset, or on the reference run; an explicit order overrides it;
- common random numbers: within a regime, trace i is generated once with every anchor of the scenario
  and the k-anchor cell is that trace restricted to the first k anchors of the order
  (:func:`physynth.studies.subset.restrict_to_anchors`). Anchors are independent in the model (own
  NLOS episodes, outages and dropouts; the shared burst clock and tag outages are shared in reality
  too), so this is a k-anchor deployment; differences between counts are then not sampling noise and
  the >= 1 availability can never fall when an anchor is added;
- every cell also reports the GDOP along the path (:mod:`physynth.studies.dop`) with all its anchors
  and with the anchors heard within the last second, and the position error of the classical trackers
  ``ls`` and ``ekf`` (:class:`TrackerColumn`, on the first :data:`TRACKER_TRACES` traces of the cell).
  Per-cell columns are :class:`CellColumn` objects listed in :data:`CELL_COLUMNS`.

Cells run in parallel (``concurrent.futures.ProcessPoolExecutor``); trace i of every cell draws from
``SeedSequence(root, spawn_key=(i, component))`` whichever worker runs it, so results do not depend on
the number of workers.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing as mp
import os
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .._json import jsonable
from ..bounds import check_budget
from ..errors import PhySynthError
from ..evaluate.metrics import Metrics, TraceSummary, fidelity_score, pool, summarize
from ..generate import compile_scenario, generate_trace
from ..progress import ProgressCallback, no_progress
from ..records import Trace
from ..scenario import Scenario
from .dop import summarize_gdop, trace_gdop
from .regimes import apply_regime, check_regime, describe_regime
from .subset import check_subset, restrict_to_anchors

DEFAULT_REGIMES = ("dense", "sparse", "degraded")


# ---------------------------------------------------------------- per-cell columns
class CellColumn(Protocol):
    """A per-cell quantity beyond the metrics: ``per_trace`` runs in a worker on one cell trace (must be
    picklable and cheap to return); ``reduce`` pools the parts of a cell's traces into named numbers.
    A column that needs the cell's scenario also has ``bind(scenario) -> CellColumn`` (:func:`bind_column`)."""

    name: str

    def per_trace(self, trace: Trace) -> Any: ...

    def reduce(self, parts: Sequence[Any]) -> dict[str, float]: ...


def bind_column(column: CellColumn, scn: Scenario) -> CellColumn:
    """``column`` for the cells of ``scn``: its ``bind(scn)`` when it has one (a column that needs the
    scenario, such as the tracker column's UWB time lag), otherwise the column itself."""
    bind = getattr(column, "bind", None)
    return bind(scn) if bind is not None else column


class GdopColumn:
    """GDOP along the path: ``gdop_*`` with every anchor of the cell, ``fresh_gdop_*`` with the anchors
    heard within the last second, ``fresh_hdop_*`` the same with the tag height known (median, P95,
    fraction of time <= 5)."""

    name = "gdop"

    def per_trace(self, trace: Trace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return trace_gdop(trace)

    def reduce(self, parts: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, float]:
        out: dict[str, float] = {}
        for j, prefix in enumerate(("gdop", "fresh_gdop", "fresh_hdop")):
            out.update(summarize_gdop(np.concatenate([p[j] for p in parts]), prefix))
        return out


TRACKERS = ("ls", "ekf")
"""The classical trackers of the tracker-error column (:mod:`physynth.track.trackers`)."""
TRACKER_TRACES = 50
"""Traces per cell the trackers run on by default: trace indices 0 .. TRACKER_TRACES - 1 (the same traces
in every count and regime, by common random numbers); with the default 50 traces per cell, every one."""


class TrackerColumn:
    """Position error of the classical trackers ``ls`` and ``ekf`` on the cell's traces.

    Each trace becomes the trackers' grid input (:func:`physynth.track.inputs.track_input`, UWB stamps
    moved back by the scenario's ``uwb.time_offset_s``); ``ls`` runs as it is, ``ekf`` with its range
    noise fitted on the trace itself (1.4826 MAD of the range residuals: the deployment's own ranging, as
    ``study tracking`` fits it on its training runs) and the IMU as control when the trace has one.
    Over the 100 Hz grid steps with known truth, per tracker ``t``:

    - ``t_fix_frac``: the fraction of steps with an estimate (``ls`` from the first range on, ``ekf``
      from its first fix: a step with a fresh range and three anchors ranged);
    - ``t_median_m``, ``t_p95_m``, ``t_rmse_m``: the 3-D error over the steps with an estimate, and
      ``t_h_median_m``, ``t_h_p95_m``, ``t_h_rmse_m`` the horizontal (E-N) error;
    - ``tracker_traces``: the number of traces the trackers ran on.

    ``max_traces`` limits the trackers to trace indices 0 .. max_traces - 1 (None: every trace).
    """

    name = "trackers"

    def __init__(self, max_traces: int | None = TRACKER_TRACES, time_offset_s: float = 0.0) -> None:
        if max_traces is not None and max_traces < 1:
            raise PhySynthError(f"the number of traces the trackers run on must be at least 1, got {max_traces}")
        self.max_traces = max_traces
        self.time_offset_s = float(time_offset_s)

    def bind(self, scn: Scenario) -> TrackerColumn:
        """The column for the cells of ``scn`` (its UWB time lag)."""
        return TrackerColumn(self.max_traces, scn.uwb.time_offset_s)

    def per_trace(self, trace: Trace) -> dict[str, tuple[int, int, np.ndarray, np.ndarray]] | None:
        from ..track.inputs import track_input
        from ..track.trackers.ekf import EkfTracker
        from ..track.trackers.ls import LsTracker

        index = int((trace.meta.get("spawn_key") or [0])[0])
        if self.max_traces is not None and index >= self.max_traces:
            return None
        inp = track_input(trace, time_offset_s=self.time_offset_s)
        truth = np.all(np.isfinite(inp.pos_rel_m), axis=1)
        out = {}
        for name in TRACKERS:
            est = LsTracker().predict_rel(inp) if name == "ls" else EkfTracker().fit([inp]).predict_rel(inp)
            have = truth & np.all(np.isfinite(est), axis=1)
            d = est[have] - inp.pos_rel_m[have]
            out[name] = (int(truth.sum()), int(have.sum()), np.linalg.norm(d, axis=1).astype(np.float32),
                         np.linalg.norm(d[:, :2], axis=1).astype(np.float32))
        return out

    def reduce(self, parts: Sequence[dict[str, tuple[int, int, np.ndarray, np.ndarray]] | None]) -> dict[str, float]:
        parts = [p for p in parts if p is not None]
        out: dict[str, float] = {"tracker_traces": float(len(parts))}
        for name in TRACKERS:
            n_truth = sum(p[name][0] for p in parts)
            out[f"{name}_fix_frac"] = sum(p[name][1] for p in parts) / n_truth if n_truth else float("nan")
            for j, tag in ((2, ""), (3, "h_")):
                e = np.concatenate([p[name][j] for p in parts]).astype(np.float64) if parts else np.array([])
                stats = ((float(np.median(e)), float(np.percentile(e, 95)), float(np.sqrt(np.mean(e * e))))
                         if e.size else (float("nan"),) * 3)
                out.update(zip((f"{name}_{tag}median_m", f"{name}_{tag}p95_m", f"{name}_{tag}rmse_m"), stats,
                               strict=True))
        return out


CELL_COLUMNS: tuple[CellColumn, ...] = (GdopColumn(), TrackerColumn())
"""Columns every cell reports besides S and availability: GDOP and the trackers' position error."""


# ---------------------------------------------------------------- results
@dataclass(frozen=True, slots=True, kw_only=True)
class AnchorStudy:
    """Result of :func:`run_anchor_study`; ``to_dict`` is the ``table.json`` form."""

    scores: dict[str, dict[int, float]]
    availability: dict[str, Any]
    columns: dict[str, dict[int, dict[str, float]]]
    order: list[str]
    order_availability: dict[str, float]
    regimes: dict[str, Any]
    reference: dict[str, Any]
    inputs: dict[str, Any]
    timing_s: dict[str, float] = field(default_factory=dict)

    @property
    def counts(self) -> list[int]:
        return sorted(next(iter(self.scores.values())))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AnchorStudy:
        """The study back from its ``table.json`` form (counts as int keys again)."""
        return cls(scores={r: {int(k): float(v) for k, v in row.items()} for r, row in d["scores"].items()},
                   availability=d["availability"],
                   columns={r: {int(k): {n: (float("inf") if v is None else v) for n, v in c.items()}
                                for k, c in row.items()} for r, row in d["columns"].items()},
                   order=list(d["order"]), order_availability=dict(d["order_availability"]),
                   regimes=d["regimes"], reference=d["reference"], inputs=d["inputs"],
                   timing_s=d.get("timing_s", {}))

    def to_dict(self) -> dict[str, Any]:
        return jsonable({
            "scores": {r: {str(k): v for k, v in row.items()} for r, row in self.scores.items()},
            "availability": self.availability,
            "columns": {r: {str(k): v for k, v in row.items()} for r, row in self.columns.items()},
            "order": self.order,
            "order_availability": self.order_availability,
            "regimes": self.regimes,
            "reference": self.reference,
            "inputs": self.inputs,
            "timing_s": self.timing_s,
        })


# ---------------------------------------------------------------- workers
def _light(s: TraceSummary) -> TraceSummary:
    """The summary without its IMU grid (anchor-independent; not shipped between processes)."""
    return dataclasses.replace(s, imu_grid_mps2=np.empty((0, 3)))


def _cell_chunk(scn: Scenario, order: Sequence[str], counts: Sequence[int], seed: int, indices: Sequence[int],
                columns: Sequence[CellColumn]) -> list[tuple[int, dict[int, tuple[TraceSummary, list[Any]]]]]:
    """Traces ``indices`` of one regime, each reduced for every anchor count."""
    cs = compile_scenario(scn)
    columns = [bind_column(c, scn) for c in columns]
    out = []
    for i in indices:
        full = generate_trace(cs, i, seed)
        per_count = {}
        for k in counts:
            tr = restrict_to_anchors(full, order[:k])
            per_count[k] = (_light(summarize(tr)), [c.per_trace(tr) for c in columns])
        out.append((i, per_count))
    return out


def _reference_chunk(scn: Scenario, seed: int, indices: Sequence[int]) -> list[tuple[int, TraceSummary]]:
    cs = compile_scenario(scn)
    return [(i, _light(summarize(generate_trace(cs, i, seed)))) for i in indices]


def _chunks(indices: Sequence[int], n_chunks: int) -> list[list[int]]:
    size = max(1, math.ceil(len(indices) / max(1, n_chunks)))
    return [list(indices[a:a + size]) for a in range(0, len(indices), size)]


@contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor | None]:
    """A process pool of ``workers`` processes (None for one worker: run in this process).

    Workers are forked when this process runs a single thread; otherwise (a progress-bar thread, say:
    fork() of a multi-threaded process can deadlock) they start from a clean ``forkserver`` process
    that has imported the generator once; ``spawn`` where neither exists. On an error or a signal the
    workers are terminated at once, their chunks unfinished (a study writes nothing until it is done).
    """
    if workers <= 1:
        yield None
        return
    methods = mp.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:  # nothing to deadlock: the cheapest start
        method = "fork"
    else:
        method = "forkserver" if "forkserver" in methods else "spawn"
    ctx = mp.get_context(method)
    if method == "forkserver":  # the server imports the generator once; every worker forks from it
        ctx.set_forkserver_preload(["physynth.studies.anchors", "physynth.studies.placement"])
    ex = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
    try:
        yield ex
    except BaseException:  # an error or a signal: the chunks under way are not waited for
        processes = list((getattr(ex, "_processes", None) or {}).values())
        ex.shutdown(wait=False, cancel_futures=True)
        for proc in processes:
            proc.terminate()
        for proc in processes:
            proc.join(5)
        raise
    ex.shutdown(wait=True)


def _map(tasks: list[tuple[Any, ...]], fn: Any, pool: ProcessPoolExecutor | None, progress: ProgressCallback,
         message: str, total: int) -> list[Any]:
    """Run ``fn(*task)`` for every task (in ``pool`` when given); results in task order."""
    done = 0
    progress(message, 0, total)
    results: list[Any] = []
    if pool is None:
        for t in tasks:
            results.append(fn(*t))
            done += len(results[-1])
            progress(message, done, total)
        return results
    futures = [pool.submit(fn, *t) for t in tasks]
    for f in futures:
        results.append(f.result())
        done += len(results[-1])
        progress(message, done, total)
    return results


# ---------------------------------------------------------------- the study
def availability_order(metrics: Metrics, ids: Sequence[str]) -> tuple[list[str], dict[str, float]]:
    """``ids`` by decreasing per-anchor fresh fraction (ties keep the given order)."""
    missing = [a for a in ids if a not in metrics.per_anchor]
    if missing:
        raise PhySynthError(f"the reference has no measurements of anchor(s) {', '.join(missing)}; "
                            "give the order explicitly")
    frac = {a: float(metrics.per_anchor[a]["fresh_frac"]) for a in ids}
    return sorted(ids, key=lambda a: -frac[a]), frac


def run_anchor_study(scn: Scenario, *, real: Sequence[Trace] | None = None, n: int = 50, seed: int = 0,
                     counts: Sequence[int] | None = None, regimes: Sequence[str] = DEFAULT_REGIMES,
                     order: Sequence[str] | None = None, workers: int | None = None,
                     columns: Sequence[CellColumn] = CELL_COLUMNS,
                     progress: ProgressCallback | None = None, force: bool = False) -> AnchorStudy:
    """Anchor count x regime study of ``scn``.

    Parameters
    ----------
    scn : Scenario
        The deployment with every candidate anchor.
    real : sequence of Trace, optional
        Real traces: the reference of every cell, and the source of the availability order.
    n : int
        Traces per cell (and in the reference run without ``real``).
    seed : int
        Root seed: trace i of every cell uses ``SeedSequence(seed, spawn_key=(i, component))``.
    counts : sequence of int, optional
        Anchor counts (default 1 .. number of anchors).
    regimes : sequence of str
        Regime names (:data:`physynth.studies.regimes.REGIMES`).
    order : sequence of str, optional
        Anchor ids in the order they are added (default: decreasing availability on the reference).
    workers : int, optional
        Processes (default: all cores); 1 runs in this process. Results do not depend on it.
    columns : sequence of CellColumn
        Per-cell columns beyond S and availability (default: GDOP).
    progress : callable, optional
        ``progress(message, done, total)`` per trace.
    force : bool
        Go ahead even when the traces the study generates (``n`` per regime, and ``n`` for the reference
        run without ``real``) exceed the size budget (:func:`physynth.bounds.check_budget`, checked
        before any work).

    Raises
    ------
    PhySynthError
        One line: n < 1, counts outside 1 .. number of anchors, an unknown regime or anchor id.
    BudgetError
        Unless ``force``: the study's traces exceed the size budget.
    """
    progress = progress or no_progress
    t_start = time.perf_counter()
    if n < 1:
        raise PhySynthError(f"the number of traces per cell must be at least 1, got {n}")
    ids = list(scn.anchor_ids)
    counts = sorted(set(range(1, len(ids) + 1) if counts is None else (int(k) for k in counts)))
    bad = [k for k in counts if not 1 <= k <= len(ids)]
    if bad:
        shown = ", ".join(map(str, bad[:5])) + (f", ... ({len(bad)} in all)" if len(bad) > 5 else "")
        raise PhySynthError(f"anchor counts must lie in 1..{len(ids)} (the scenario's anchors), got {shown}")
    regimes = [check_regime(r) for r in regimes]
    if not regimes:
        raise PhySynthError("no regime given")
    if len(set(regimes)) != len(regimes):
        raise PhySynthError(f"a regime is given twice: {', '.join(regimes)}")
    if real:  # the real run is the reference of every cell: it must have been measured with these anchors
        from ..validate.compare import describe_anchor_mismatch

        for tr in real:
            why = describe_anchor_mismatch(list(tr.anchors.ids), ids, f"scenario '{scn.name}'")
            if why:
                raise PhySynthError(f"{why}: the study needs a real run of the scenario's anchors (calibrate "
                                    "the scenario on it, or choose the scenario of that site)")
    if order is not None:  # checked before any work
        order = check_subset(order, ids, "the anchor order")
        if len(order) < max(counts):
            raise PhySynthError(f"the order names {len(order)} anchor(s) but counts go up to {max(counts)}")
    workers = max(1, int(workers or os.cpu_count() or 1))
    check_budget(scn, n * (len(regimes) + (real is None)), force=force, writes=False,  # every trace it generates,
                 processes=workers)  # on all its processes together
    n_chunks = 2 * workers
    with worker_pool(workers) as executor:  # one pool for the reference run and the cells
        return _run(scn, real=real, n=n, seed=seed, counts=counts, regimes=regimes, order=order, workers=workers,
                    n_chunks=n_chunks, executor=executor, columns=columns, progress=progress, t_start=t_start)


def _run(scn: Scenario, *, real: Sequence[Trace] | None, n: int, seed: int, counts: list[int], regimes: list[str],
         order: list[str] | None, workers: int, n_chunks: int, executor: ProcessPoolExecutor | None,
         columns: Sequence[CellColumn], progress: ProgressCallback, t_start: float) -> AnchorStudy:
    ids = list(scn.anchor_ids)

    # reference and order
    if real is not None:
        if not real:
            raise PhySynthError("the real dataset holds no traces")
        ref_metrics = pool([summarize(t) for t in real])
        ref_info: dict[str, Any] = {"kind": "real", "n_traces": len(real),
                                    "anchors": list(ref_metrics.per_anchor)}
    else:
        ref_idx = list(range(n, 2 * n))
        parts = _map([(scn, seed, c) for c in _chunks(ref_idx, n_chunks)], _reference_chunk, executor, progress,
                     "anchor study: reference run", n)
        ref_metrics = pool([s for part in parts for _, s in part])
        ref_info = {"kind": "reference run", "n_traces": n, "trace_indices": [n, 2 * n - 1],
                    "anchors": ids}
    if order is None:
        order_ids, frac = availability_order(ref_metrics, ids)
        order_source = ref_info["kind"]
    else:
        order_ids = list(order)
        frac = {a: float(ref_metrics.per_anchor.get(a, {}).get("fresh_frac", float("nan"))) for a in order_ids}
        order_source = "given"
    t_ref = time.perf_counter()

    # cells: regimes x chunks of traces, each trace reduced for every count
    tasks, owners = [], []
    for r in regimes:
        rs = apply_regime(scn, r)
        for c in _chunks(list(range(n)), max(1, n_chunks // len(regimes))):
            tasks.append((rs, order_ids, counts, seed, c, tuple(columns)))
            owners.append(r)
    results = _map(tasks, _cell_chunk, executor, progress, "anchor study: cells", n * len(regimes))
    collected: dict[str, list[tuple[int, dict]]] = {r: [] for r in regimes}
    for r, part in zip(owners, results, strict=True):
        collected[r] += part

    scores: dict[str, dict[int, float]] = {}
    avail: dict[str, Any] = {"reference": {"ge1": ref_metrics.uwb_ge1_frac, "ge2": ref_metrics.uwb_ge2_frac}}
    cols: dict[str, dict[int, dict[str, float]]] = {}
    for r in regimes:
        rows = sorted(collected[r], key=lambda x: x[0])
        scores[r], avail[r], cols[r] = {}, {}, {}
        for k in counts:
            m = pool([pc[k][0] for _, pc in rows])
            scores[r][k] = fidelity_score(ref_metrics, m)
            avail[r][str(k)] = {"ge1": m.uwb_ge1_frac, "ge2": m.uwb_ge2_frac,
                                "residual_median_m": m.residual_median_m, "abs_residual_p95_m": m.abs_residual_p95_m,
                                "mean_aoi_s": m.mean_aoi_s}
            cols[r][k] = {}
            for j, col in enumerate(columns):
                cols[r][k].update(col.reduce([pc[k][1][j] for _, pc in rows]))
    t_end = time.perf_counter()
    return AnchorStudy(
        scores=scores, availability=avail, columns=cols, order=order_ids, order_availability=frac,
        regimes={r: describe_regime(r) for r in regimes},
        reference={**ref_info, "ge1": ref_metrics.uwb_ge1_frac, "ge2": ref_metrics.uwb_ge2_frac,
                   "residual_median_m": ref_metrics.residual_median_m,
                   "abs_residual_p95_m": ref_metrics.abs_residual_p95_m, "order_source": order_source},
        inputs={"scenario": scn.name, "n_traces_per_cell": n, "root_seed": int(seed), "counts": counts,
                "workers": workers, "coupling": "common random numbers: the k-anchor cell is the full-layout "
                                                "trace restricted to the first k anchors of the order"},
        timing_s={"reference": t_ref - t_start, "cells": t_end - t_ref, "total": t_end - t_start},
    )


# ---------------------------------------------------------------- outputs
STUDY_FILES = ("table.json", "table.md", "anchors.png")


def _fmt(x: Any, digits: int = 3) -> str:
    return "-" if not isinstance(x, (int, float)) or not math.isfinite(x) else f"{x:.{digits}f}"


def anchor_table_md(study: AnchorStudy) -> str:
    """Table III of the paper for this study (rows: anchor count, descending; columns: regimes, mean)."""
    regimes = list(study.scores)
    counts = sorted(study.counts, reverse=True)
    ref = study.reference
    how = "given" if ref["order_source"] == "given" else f"decreasing availability on the {ref['order_source']}"
    lines = [f"# Anchor study: {study.inputs['scenario']}", "",
             f"Fidelity score S = d_avail + d_med/10 + d_P95/20 against the {ref['kind']} "
             f"({ref['n_traces']} trace(s), anchors {', '.join(ref['anchors'])}); lower is better. "
             f"{study.inputs['n_traces_per_cell']} synthetic traces per cell, root seed {study.inputs['root_seed']}.",
             f"Anchors added in this order ({how}): "
             + ", ".join(f"{a} ({_fmt(study.order_availability.get(a))})" for a in study.order) + ".", "",
             "| Anchors | " + " | ".join(r.capitalize() for r in regimes) + " | Mean |",
             "|---|" + "---|" * (len(regimes) + 1)]
    for k in counts:
        row = [study.scores[r][k] for r in regimes]
        lines.append(f"| {k} | " + " | ".join(_fmt(v) for v in row) + f" | {_fmt(float(np.mean(row)))} |")
    means = [float(np.mean([study.scores[r][k] for k in counts])) for r in regimes]
    lines.append("| Mean | " + " | ".join(_fmt(v) for v in means) + " | - |")
    lines += ["", f"Availability (fraction of 10 ms grid bins with >= 1 / >= 2 fresh anchors); reference "
                  f"{_fmt(ref['ge1'])} / {_fmt(ref['ge2'])}.", "",
              "| Anchors | " + " | ".join(f"{r} >=1 | {r} >=2" for r in regimes) + " |",
              "|---|" + "---|---|" * len(regimes)]
    for k in counts:
        cells = [f"{_fmt(study.availability[r][str(k)]['ge1'])} | {_fmt(study.availability[r][str(k)]['ge2'])}"
                 for r in regimes]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines += ["", "GDOP along the path (median; fraction of time <= 5): with every anchor of the cell, with the "
                  "anchors heard in the last second ('fresh'), and the fresh HDOP with the tag height known. "
                  "'-' = no fix for at least half of the time.", "",
              "| Anchors | " + " | ".join(f"{r} GDOP | {r} fresh | {r} fresh HDOP" for r in regimes) + " |",
              "|---|" + "---|---|---|" * len(regimes)]
    for k in counts:
        cells = []
        for r in regimes:
            c = study.columns[r][k]
            cells.append(" | ".join(f"{_fmt(c.get(p + '_median'), 1)} ({_fmt(c.get(p + '_le5_frac'), 2)})"
                                    for p in ("gdop", "fresh_gdop", "fresh_hdop")))
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    if any("ekf_fix_frac" in study.columns[r][k] for r in regimes for k in counts):
        n_tr = int(min(study.columns[r][k].get("tracker_traces", 0) for r in regimes for k in counts))
        for title, tag in (("3-D", ""), ("horizontal (E-N)", "h_")):
            lines += ["", f"Tracker position error, {title} [m]: median (P95) over the 100 Hz grid steps with an "
                          "estimate" + ("; fraction of the time with an estimate" if not tag else "")
                      + f"; {n_tr} trace(s) per cell. '-' = no estimate.", "",
                      "| Anchors | " + " | ".join(f"{r} {t}" for r in regimes for t in TRACKERS) + " |",
                      "|---|" + "---|" * (len(regimes) * len(TRACKERS))]
            for k in counts:
                cells = []
                for r in regimes:
                    c = study.columns[r][k]
                    for t in TRACKERS:
                        cell = f"{_fmt(c.get(f'{t}_{tag}median_m'), 1)} ({_fmt(c.get(f'{t}_{tag}p95_m'), 1)})"
                        if not tag:
                            cell += f"; {_fmt(c.get(f'{t}_fix_frac'), 2)}"
                        cells.append(cell)
                lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines += ["", "Regimes:", ""]
    for r, d in study.regimes.items():
        lines.append(f"- {r}: {d['summary']} ({'; '.join(d['changes']) or 'no change'})")
    lines += ["", f"Run time {study.timing_s.get('total', float('nan')):.1f} s on {study.inputs['workers']} "
                  "worker process(es).", ""]
    return "\n".join(lines)


def anchor_figure_png(study: AnchorStudy) -> bytes:
    """Figure 6 of the paper: (left) S against anchor count per regime; (middle) >= 1 and >= 2
    availability against count per regime, the reference as horizontal lines; (right, when the study
    has the tracker column) the median 3-D position error of ``ekf`` and ``ls`` against count."""
    from ..validate.figures import figure_png, require_matplotlib

    figure_cls, canvas_cls = require_matplotlib()
    counts = study.counts
    trackers = any("ekf_median_m" in study.columns[r][k] for r in study.scores for k in counts)
    fig = figure_cls(figsize=(16.5 if trackers else 11, 4.8))
    axes = fig.subplots(1, 3 if trackers else 2)
    ax1, ax2 = axes[0], axes[1]
    colors = {"nominal": "k", "dense": "tab:blue", "sparse": "tab:orange", "degraded": "tab:red"}
    for r in study.scores:
        c = colors.get(r)
        ax1.plot(counts, [study.scores[r][k] for k in counts], "o-", color=c, label=r)
        ax2.plot(counts, [study.availability[r][str(k)]["ge1"] for k in counts], "o-", color=c, label=f"{r} >= 1")
        ax2.plot(counts, [study.availability[r][str(k)]["ge2"] for k in counts], "s--", color=c, label=f"{r} >= 2")
        if trackers:
            for t, style in (("ekf", "o-"), ("ls", "s:")):
                y = [study.columns[r][k].get(f"{t}_median_m", float("nan")) for k in counts]
                axes[2].plot(counts, [v if math.isfinite(v) else float("nan") for v in y], style, color=c,
                             label=f"{r} {t}")
    ref = study.reference
    ax2.axhline(ref["ge1"], color="0.3", lw=1.5, label=f"{ref['kind']} >= 1")
    ax2.axhline(ref["ge2"], color="0.3", lw=1.5, ls=":", label=f"{ref['kind']} >= 2")
    ax1.set_xlabel("anchors")
    ax1.set_ylabel("fidelity score S (lower is better)")
    ax1.set_title("S against anchor count")
    ax1.legend()
    ax2.set_xlabel("anchors")
    ax2.set_ylabel("fraction of 10 ms bins")
    ax2.set_title(">= 1 and >= 2 fresh anchors")
    ax2.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.16))
    if trackers:
        ax3 = axes[2]
        ax3.set_xlabel("anchors")
        ax3.set_ylabel("median 3-D position error [m]")
        ax3.set_yscale("log")
        ax3.set_title("tracker error: ekf (solid), ls (dotted)")
        ax3.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.16))
    for ax in axes:
        ax.set_xticks(counts)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return figure_png(fig, canvas_cls)


def write_anchor_study(study: AnchorStudy, out: str | os.PathLike, *, figures: bool = True,
                       overwrite: bool = False) -> list[str]:
    """Write ``table.json``, ``table.md`` and (with ``figures``) ``anchors.png`` into ``out`` (atomically).

    Raises :class:`~physynth.errors.OutputExistsError` when ``out`` holds a table and not ``overwrite``.
    """
    import json
    from pathlib import Path

    from ..errors import OutputExistsError
    from ..io.atomic import atomic_write_bytes, atomic_write_text

    out = Path(out)
    if (out / "table.json").exists() and not overwrite:
        raise OutputExistsError(out, "holds an anchor study")
    if out.exists() and not out.is_dir():
        raise PhySynthError(f"output {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "table.json", json.dumps(study.to_dict(), indent=1) + "\n")
    atomic_write_text(out / "table.md", anchor_table_md(study))
    written = ["table.json", "table.md"]
    if figures:
        atomic_write_bytes(out / "anchors.png", anchor_figure_png(study))
        written.append("anchors.png")
    return written
