"""CSV export: a folder with one CSV file per table, the same columns as the Parquet tables.

``truth.csv``, ``imu.csv``, ``uwb.csv``, ``anchors.csv`` (each with a ``trace`` column),
``dataset.json`` and, for a dataset of several shards, ``traces.jsonl`` (per-trace metadata). The
tables are copied one Parquet row group at a time by Arrow's CSV writer: floats in their shortest
round-trip form (float64 columns read back exactly; float32 columns of generated datasets as
float32), ``nan`` for a range not delivered, an empty field for an unknown ``nlos``, strings quoted,
a header line first (pandas.read_csv and Python's csv module read it as is). The files copied are
those the dataset's integrity record lists (:func:`~physynth.io.dataset.table_files`), once the part
being exported has been read trace by trace to check it (:mod:`.parts`: one part per shard of the dataset,
concatenated when all are written).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..dataset import TABLES, iter_trace_meta, table_files


def write_csv_tables(dataset: Path, meta: dict[str, Any], path: Path, *, header: bool = True) -> None:
    """Write the tables of ``dataset`` (the files its ``meta`` lists) as CSV files in the new folder ``path``;
    ``header``: a header line first (the first part of an export has it, the others are appended to it)."""
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    path.mkdir(parents=True)
    options = pcsv.WriteOptions(include_header=header)
    for name in TABLES:
        writer = None
        try:
            for f in table_files(dataset, name, meta):
                pf = pq.ParquetFile(f)
                if writer is None:
                    writer = pcsv.CSVWriter(path / f"{name}.csv", pf.schema_arrow, write_options=options)
                for g in range(pf.metadata.num_row_groups):
                    writer.write_table(pf.read_row_group(g))
        finally:
            if writer is not None:
                writer.close()


def finish_csv(dataset: Path, meta: dict[str, Any], path: Path) -> None:
    """Add ``dataset.json`` and, for a dataset of several shards, ``traces.jsonl`` to the CSV folder ``path``."""
    (path / "dataset.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
    if "traces" not in meta:  # a dataset of several shards keeps its per-trace metadata apart: one file here
        with open(path / "traces.jsonl", "w", encoding="utf-8") as fh:
            for _, m in iter_trace_meta(dataset, meta):
                fh.write(json.dumps(m) + "\n")
