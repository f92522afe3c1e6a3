"""CSV export: a folder with one CSV file per table, the same columns as the Parquet tables.

``truth.csv``, ``imu.csv``, ``uwb.csv``, ``anchors.csv`` (each with a ``trace`` column),
``dataset.json`` and, for a dataset of several shards, ``traces.jsonl`` (per-trace metadata). The
tables are copied one Parquet row group at a time by Arrow's CSV writer: floats in their shortest
round-trip form (float64 columns read back exactly; float32 columns of generated datasets as
float32), ``nan`` for a range not delivered, an empty field for an unknown ``nlos``, strings quoted,
a header line first (pandas.read_csv and Python's csv module read it as is). The files copied are
those the dataset's integrity record lists (:func:`~physynth.io.dataset.table_files`), once
:func:`physynth.io.export.export_dataset` has read the dataset trace by trace to check it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..dataset import TABLES, iter_trace_meta, table_files


def write_csv(dataset: Path, meta: dict[str, Any], path: Path, progress=None) -> None:
    """Write the tables of ``dataset`` as CSV files in the new folder ``path``."""
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    path.mkdir(parents=True)
    groups = [(name, f, g) for name in TABLES for f in table_files(dataset, name, meta)
              for g in range(pq.ParquetFile(f).metadata.num_row_groups)]
    writers: dict[str, Any] = {}
    try:
        for k, (name, f, g) in enumerate(groups):
            table = pq.ParquetFile(f).read_row_group(g)
            if name not in writers:
                writers[name] = pcsv.CSVWriter(path / f"{name}.csv", table.schema)
            writers[name].write_table(table)
            if progress is not None:
                progress("exporting to csv (row groups)", k + 1, len(groups))
    finally:
        for w in writers.values():
            w.close()
    (path / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
    if "traces" not in meta:  # a dataset of several shards keeps its per-trace metadata apart: one file here
        with open(path / "traces.jsonl", "w", encoding="utf-8") as fh:
            for _, m in iter_trace_meta(dataset, meta):
                fh.write(json.dumps(m) + "\n")
