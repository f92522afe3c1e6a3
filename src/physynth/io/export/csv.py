"""CSV export: a folder with one CSV file per table, the same columns as the Parquet tables.

``truth.csv``, ``imu.csv``, ``uwb.csv``, ``anchors.csv`` (each with a ``trace`` column),
``dataset.json`` and, for a dataset of several shards, ``traces.jsonl`` (per-trace metadata). The tables
are copied one Parquet row group at a time by polars' CSV writer (which formats on every core, three to
four times faster than Arrow's: ``benchmarks/bench_export.py``), the tables at the same time
(:func:`write_csv_tables`): floats in their shortest round-trip form (float64 columns read back exactly;
float32 columns of generated datasets as float32; a whole number keeps its ``.0``), ``NaN`` for a range
not delivered, an empty field for an unknown ``nlos``, ``true``/``false``, strings quoted only where
they hold a comma, quote or line break, a header line first (pandas.read_csv and Python's csv module
read it as is). The files copied are those the dataset's integrity record lists
(:func:`~physynth.io.dataset.table_files`), once they have been checked against it
(:func:`check_tables`: sizes, row counts, SHA-256, trace ids, the columns of each table; a dataset
without the record is read trace by trace instead, as every reader does); one part per shard of the
dataset (:mod:`.parts`), concatenated when all are written.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import DatasetError
from .. import integrity
from ..dataset import TABLES, iter_trace_meta, read_ahead, table_files
from ..pagecache import WriteBehind
from ..tables import OPTIONAL_COLUMNS, arrow_schemas, run_starts, to_numpy


def check_tables(dataset: Path, meta: dict[str, Any]) -> bool:
    """Check the tables ``meta`` lists against its integrity record (sizes, row counts, SHA-256 unless
    ``PHYSYNTH_SKIP_HASHES``, trace ids) and each table file's columns (from its footer); False when
    ``meta`` has no integrity record (nothing to check against: read the traces instead)."""
    import pyarrow.parquet as pq

    if not isinstance(meta.get("files"), dict):
        return False
    integrity.check_dataset(dataset, meta, hashes=not integrity.environ_skip_hashes())
    for name in TABLES:
        optional = {c for group in OPTIONAL_COLUMNS.get(name, {}).values() for c in group}
        required = [c for c in arrow_schemas()[0][name].names if c not in optional]
        for f in table_files(dataset, name, meta):
            missing = sorted(set(required) - set(pq.ParquetFile(f).schema_arrow.names))
            if missing:
                raise DatasetError(f"{f}: missing column(s) {', '.join(missing)}")
    return True


def write_csv_tables(dataset: Path, meta: dict[str, Any], path: Path, *, header: bool = True,
                     on_trace: Callable[[], None] | None = None, append: bool = False,
                     behind: bool = False) -> None:
    """Write the tables of ``dataset`` (the files its ``meta`` lists) as CSV files in the new folder ``path``
    or, with ``append``, append their rows to the CSV files in the folder ``path``; ``header``: a header
    line first (the first part of an export has it, the others are appended to it); ``on_trace()`` once
    per trace, as the rows of its UWB table are written (for the traces without, at the end); ``behind``:
    the files are the export's own, not read again, and written behind (:mod:`physynth.io.pagecache`).

    The tables are written at the same time, each file by one thread in row order (polars formats without
    the GIL; one table at a time left a core idle a quarter of the time): the UWB table, which reports the
    traces, in the caller's thread, the others on threads of their own, which stop at their next row group
    when the caller stops."""
    from concurrent.futures import ThreadPoolExecutor

    if not append:
        path.mkdir(parents=True)
    names = [name for name in TABLES if table_files(dataset, name, meta)]
    others = [name for name in names if name != "uwb"]
    stop = threading.Event()
    seen: set[int] = set()
    with ThreadPoolExecutor(max(1, len(others)), thread_name_prefix="physynth-csv") as pool:
        futures = [pool.submit(_write_table, dataset, meta, path, name, header, append, behind, stop, None, seen)
                   for name in others]
        try:
            if "uwb" in names:
                _write_table(dataset, meta, path, "uwb", header, append, behind, stop, on_trace, seen)
            for f in futures:
                f.result()
        finally:
            stop.set()  # a table still being written (the caller failed or was stopped) ends at its next row group
    n = meta.get("n_traces")
    for _ in range(max(0, n - len(seen)) if on_trace is not None and isinstance(n, int) else 0):
        on_trace()


def _write_table(dataset: Path, meta: dict[str, Any], path: Path, name: str, header: bool, append: bool,
                 behind: bool, stop: threading.Event, on_trace: Callable[[], None] | None, seen: set[int]) -> None:
    """One table of :func:`write_csv_tables`, row group by row group (``on_trace`` for each new trace id,
    gathered in ``seen``); returns early once ``stop`` is set."""
    import polars as pl
    import pyarrow.parquet as pq

    with open(path / f"{name}.csv", "ab" if append else "wb") as fh:
        first = header
        written = WriteBehind(fh.fileno(), fh.tell()) if behind else None
        for f in table_files(dataset, name, meta):
            pf = pq.ParquetFile(f)
            for table in read_ahead(pf.read_row_group, range(pf.metadata.num_row_groups)):
                if stop.is_set():
                    return
                pl.from_arrow(table).write_csv(fh, include_header=first)
                first = False
                if written is not None:  # gigabytes that nothing reads back soon
                    fh.flush()
                    written.advance(fh.tell())
                if on_trace is not None:
                    new = _trace_ids(to_numpy(table.column("trace"))) - seen
                    seen |= new
                    for _ in new:
                        on_trace()
            if first:  # a table without rows: its header line alone
                pl.from_arrow(pf.schema_arrow.empty_table()).write_csv(fh, include_header=True)
                first = False


def _trace_ids(trace: np.ndarray) -> set[int]:
    """The trace ids of a table's rows: the first of each run of equal ids (rows are grouped by trace, so a
    run per trace; one pass, where ``np.unique`` sorts: a tenth of the CSV export's time on its main thread)."""
    return set(trace[run_starts(trace)].tolist())


def finish_csv(dataset: Path, meta: dict[str, Any], path: Path) -> None:
    """Add ``dataset.json`` and, for a dataset of several shards, ``traces.jsonl`` to the CSV folder ``path``."""
    (path / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
    if "traces" not in meta:  # a dataset of several shards keeps its per-trace metadata apart: one file here
        with open(path / "traces.jsonl", "w", encoding="utf-8") as fh:
            for _, m in iter_trace_meta(dataset, meta):
                fh.write(json.dumps(m) + "\n")
