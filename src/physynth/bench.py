"""Throughput of the generator: what ``physynth bench`` measures and prints.

- ``traces_per_s_memory``: traces of the scenario generated in memory, in this process (one core);
- ``traces_per_s_parquet``: traces generated and written as a dataset by one worker, as ``generate -w 1``
  does: generated in this process, written by a writer thread, or from
  :data:`~physynth.io.writer_process.MIN_TRACES` traces on by its writer process where a core is to spare
  (:mod:`physynth.io.writer_process`);
- ``scaling_efficiency``: rate with ``workers`` worker processes on an embedded Dask cluster divided by
  ``workers`` times the rate of one worker on one core (writing in its own process, without a writer
  process) in the same run (``n_scaling`` traces, shards of a quarter per worker), both end to end: the
  cluster's start is included; with ``repeat`` > 1 the two runs alternate and the best rate of each is kept;
- ``peak_rss_mb``: the largest resident memory of this process or of any worker process it waited for;
- ``scaling_efficiency_steady``: the same ratio with the cluster's start and stop taken off the run with
  workers (``cluster_start_stop_s``: an embedded cluster of ``workers`` started, given one trace each and
  stopped, timed alone): what a long run (a million traces) scales by, where a start of a second or two
  does not count;
- ``scaling_caveat``: one line when the scaling run was too short to mean much (its one-worker half took
  less than :data:`SCALING_MIN_RUN_S`: the cluster's start then dominates the rate with workers), else None;
- ``export_vs_parquet`` (with ``exports``): per export format (``hdf5``, ``csv``, ``rosbag2`` in MCAP,
  those whose libraries are installed), the time to export the ``n`` traces in this process divided by the
  time to generate the same traces to Parquet in this process, measured alternately in the same run
  (best of ``repeat`` each; each after ``sync``, so that none pays for the writeback of the one before);
  ``export_s`` and ``parquet_s`` hold the times.

The figures depend on the machine and on what else runs on it: run on a quiet machine, and compare
ratios measured side by side in one run. ``machine.others_cpu_share`` tells how quiet it was: the share of
the cores' time that other processes took during the run (:class:`OthersCpu`).
"""

from __future__ import annotations

import os
import platform
import resource
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from .errors import PhySynthError
from .generate import compile_scenario, generate_trace
from .progress import ProgressCallback, no_progress
from .scenario import Scenario

SCALING_MIN_RUN_S = 15.0
"""A scaling run whose one-worker half takes less than this [s] is short enough for the start and stop of
the worker processes (0.7-1 s for two here, 2026-11-27: docs/scale.md) to weigh in: its
``scaling_efficiency`` and ``scaling_efficiency_steady`` come with a caveat."""


def scaling_caveat(one_worker_s: float, workers: int) -> str | None:
    """The caveat of a scaling run whose one-worker half took ``one_worker_s`` [s] (None when long enough)."""
    if one_worker_s >= SCALING_MIN_RUN_S:
        return None
    return (f"scaling_efficiency and scaling_efficiency_steady come from a {one_worker_s:.2g} s run on one worker "
            f"(under {SCALING_MIN_RUN_S:g} s), where starting the {workers} worker processes weighs in: longer runs "
            "scale better")


def peak_rss_mb() -> float:
    """Peak resident memory of this process and of its finished children [MB] (Linux: ru_maxrss in kB)."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, kids) / 1024.0


def run_bench(scn: Scenario, *, n: int = 200, n_scaling: int = 0, workers: int = 0, repeat: int = 1,
              exports: bool = False, directory: str | os.PathLike | None = None,
              progress: ProgressCallback = no_progress) -> dict[str, Any]:
    """Measure the generator; returns the figures of the module docstring plus the machine.

    Parameters
    ----------
    n : int
        Traces per one-core measurement.
    n_scaling : int
        Traces of the scaling measurement (0: twenty times ``n``, a run of about 20 s on one worker of
        this machine). Starting the cluster's worker processes costs about a second once (each imports
        NumPy, pyarrow and Dask), so small runs understate the scaling of long ones.
    workers : int
        Workers of the scaling measurement (0: all cores; 1 skips it).
    directory : path, optional
        Folder in which the measurements write their datasets and exports (a new folder inside it, removed
        at the end; default: the system's temporary folder): the disk you will write to, since writing
        speeds differ from disk to disk (and on some machines the temporary folder is slow to create files).
    repeat : int
        Repetitions of every measurement; the best rate of each is kept. The scaling runs alternate
        (one worker, ``workers``, one worker, ...), so that the machine's slower and faster spells
        (10-30 % on a shared 2-core machine, docs/scale.md) reach both sides of the ratio alike.
    """
    from ._args import check_int
    from .parallel import available_cores
    from .workflows import generate_dataset

    n, repeat = check_int(n, "n", minimum=1), check_int(repeat, "repeat", minimum=1)
    n_scaling, workers = check_int(n_scaling, "n_scaling"), check_int(workers, "workers")
    others = OthersCpu()
    if directory is not None and not Path(directory).is_dir():
        raise PhySynthError(f"directory {directory} is not an existing folder")
    cores = available_cores()
    workers = workers or cores
    cs = compile_scenario(scn)
    generate_trace(cs, 0, 0)  # warm-up: imports, caches
    best_mem = 0.0
    for r in range(repeat):
        t0 = time.perf_counter()
        for i in range(n):
            generate_trace(cs, i, r)
            progress("in memory", r * n + i + 1, repeat * n)
        best_mem = max(best_mem, n / (time.perf_counter() - t0))
    tmp = Path(tempfile.mkdtemp(prefix="physynth-bench-", dir=directory))
    out: dict[str, Any] = {}
    try:
        best_pq, size = 0.0, 0
        for r in range(repeat):
            t0 = time.perf_counter()
            path, _ = generate_dataset(scn, n, tmp / f"one{r}", seed=r, workers=1,
                                       progress=lambda m, d=None, t=None, r=r: progress(
                                           "to Parquet", None if d is None else r * n + d, repeat * n))
            best_pq = max(best_pq, n / (time.perf_counter() - t0))
            size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
            shutil.rmtree(path)
        out.update(traces_per_s_memory=round(best_mem, 1), traces_per_s_parquet=round(best_pq, 1),
                   mb_per_trace_on_disk=round(size / n / 1e6, 3))
        out["export_vs_parquet"] = _exports(scn, n, repeat, tmp, progress) if exports else None
        if workers > 1:
            out.update(_scaling(scn, n_scaling or 20 * n, workers, repeat, tmp, progress))
        else:
            out.update(traces_per_s_workers=None, scaling_efficiency=None, cluster_start_stop_s=None,
                       scaling_efficiency_steady=None, scaling_caveat=None)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["peak_rss_mb"] = round(peak_rss_mb(), 1)
    out["machine"] = {"cores": cores, "workers": workers, "cpu": _cpu_name(), "python": platform.python_version(),
                      "load_average_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
                      "others_cpu_share": others.share()}
    out["scenario"] = scn.name
    out["n"] = n
    return out


def _scaling(scn: Scenario, ns: int, workers: int, repeat: int, tmp: Path,
             progress: ProgressCallback) -> dict[str, Any]:
    """The scaling figures of :func:`run_bench`: ``ns`` traces on one worker (in this process) and on
    ``workers`` (an embedded cluster), alternated ``repeat`` times, best rate of each; and the cluster's
    start and stop alone (``workers`` one-trace shards, best of ``repeat``), which the steady-state figure
    takes off the run with workers."""
    from .workflows import generate_dataset

    shard = max(1, ns // (4 * workers))
    rates = {1: 0.0, workers: 0.0}
    best_s = {1: float("inf"), workers: float("inf")}
    overhead = float("inf")
    for _ in range(repeat):  # one and `workers` alternated, so that a slower spell hits both
        for w in (1, workers):
            t0 = time.perf_counter()
            path, _ = generate_dataset(scn, ns, tmp / f"w{w}", seed=1, workers=w, shard_traces=shard,
                                       writer_process=False,  # one worker on one core: the per-core rate
                                       progress=lambda m, d=None, t=None, w=w: progress(
                                           f"scaling, {w} worker(s)", d, t))
            best_s[w] = min(best_s[w], time.perf_counter() - t0)
            rates[w] = ns / best_s[w]
            shutil.rmtree(path)
        t0 = time.perf_counter()
        path, _ = generate_dataset(scn, workers, tmp / "start", seed=1, workers=workers, shard_traces=1)
        overhead = min(overhead, time.perf_counter() - t0)
        shutil.rmtree(path)
    eff = rates[workers] / (workers * rates[1])
    steady_s = best_s[workers] - overhead
    steady = ns / steady_s / (workers * rates[1]) if steady_s > 0 else None
    return {"traces_per_s_workers": {str(w): round(v, 1) for w, v in rates.items()},
            "scaling_efficiency": round(eff, 3),
            "cluster_start_stop_s": round(overhead, 2),
            "scaling_efficiency_steady": None if steady is None else round(steady, 3),
            "scaling_caveat": scaling_caveat(best_s[1], workers)}


def export_formats() -> list[str]:
    """The export formats whose libraries are installed."""
    import importlib.util

    return [fmt for fmt, module in (("hdf5", "h5py"), ("csv", "polars"), ("rosbag2", "rosbags"))
            if importlib.util.find_spec(module) is not None]


def _exports(scn: Scenario, n: int, repeat: int, tmp: Path, progress: ProgressCallback) -> dict[str, Any]:
    """Each export of ``n`` traces against generating them to Parquet, alternated ``repeat`` times in this
    process (best time of each); outputs are removed as soon as they are timed."""
    from .io.export import export_dataset
    from .workflows import generate_dataset

    formats = export_formats()
    best = {k: float("inf") for k in ("parquet", *formats)}
    for r in range(repeat):
        _sync()
        t0 = time.perf_counter()
        src, _ = generate_dataset(scn, n, tmp / "src", seed=r, workers=1, overwrite=True,
                                  progress=lambda m, d=None, t=None: progress("to Parquet (exports)", d, t))
        best["parquet"] = min(best["parquet"], time.perf_counter() - t0)
        for fmt in formats:
            dest = tmp / f"export.{fmt}"
            _sync()
            t0 = time.perf_counter()
            export_dataset(src, dest, fmt, progress=lambda m, d=None, t=None, fmt=fmt: progress(
                f"export to {fmt}", d, t) if d is not None else None)
            best[fmt] = min(best[fmt], time.perf_counter() - t0)
            shutil.rmtree(dest) if dest.is_dir() else dest.unlink()
    return {"ratios": {fmt: round(best[fmt] / best["parquet"], 2) for fmt in formats},
            "export_s": {fmt: round(best[fmt], 2) for fmt in formats}, "parquet_s": round(best["parquet"], 2),
            "rosbag2_storage": "mcap"}


class OthersCpu:
    """The share of the machine's CPU time that went to other processes (not this one, nor the children it
    waited for) from its making to :meth:`share`: system-wide busy time (Linux ``/proc/stat``; a virtual
    machine's steal time counts as busy) less this process tree's own (``os.times``), over the cores'
    time. The kernel's own threads count as others, among them those writing out what the run wrote. A
    load average counts the minute before, and this run's own work in it."""

    def __init__(self, stat: str = "/proc/stat") -> None:
        self._stat = stat
        self._start = (_busy_s(stat), _own_s(), time.perf_counter())

    def share(self) -> float | None:
        """0 (nothing else ran) to 1 (every core busy with others); None where the system does not tell."""
        busy0, own0, t0 = self._start
        busy1 = _busy_s(self._stat)
        wall, cores = time.perf_counter() - t0, os.cpu_count() or 1
        if busy0 is None or busy1 is None or wall <= 0:
            return None
        return round(min(1.0, max(0.0, (busy1 - busy0 - (_own_s() - own0)) / (wall * cores))), 3)


def _busy_s(stat: str) -> float | None:
    """Seconds of CPU time the whole machine spent busy since it started (``/proc/stat``: every state but
    idle and iowait), or None."""
    try:
        with open(stat, encoding="ascii") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    if len(fields) < 6 or fields[0] != "cpu":
        return None
    ticks = [int(v) for v in fields[1:]]
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")


def _own_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _sync() -> None:
    """What was written before on disk (``os.sync``, where there is one)."""
    if hasattr(os, "sync"):
        os.sync()


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
