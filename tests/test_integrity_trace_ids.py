"""The trace-id check of a one-shard dataset (integrity.check_trace_ids): the ids its truth table holds
against those dataset.json lists, read from the column's buffers (runs of equal ids, any row order)."""

from __future__ import annotations

import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from physynth.errors import IntegrityError
from physynth.io import integrity
from physynth.io.dataset import read_meta
from physynth.workflows import generate_dataset


@pytest.fixture
def dataset(tmp_path):
    path, _ = generate_dataset("cablecar-descending", 3, tmp_path / "ds", seed=4)
    return path


def _rewrite_truth(path, trace_column):
    """truth.parquet with its trace column replaced, and dataset.json's record of it updated (so that only
    the id check can tell)."""
    f = path / "truth.parquet"
    table = pq.read_table(f)
    table = table.set_column(table.schema.get_field_index("trace"), "trace", trace_column(table))
    pq.write_table(table, f)
    meta = read_meta(path)
    meta["files"]["truth.parquet"] = integrity.file_records(path, {"truth.parquet": table.num_rows})["truth.parquet"]
    (path / "dataset.json").write_text(json.dumps(meta), encoding="utf-8")
    return read_meta(path)


def test_ids_as_listed_pass_in_any_row_order(dataset):
    integrity.check_trace_ids(dataset, read_meta(dataset))
    meta = _rewrite_truth(dataset, lambda t: pa.array(t.column("trace").to_numpy()[::-1].copy()))
    integrity.check_trace_ids(dataset, meta)  # the same ids, rows reversed


def test_a_missing_trace_and_an_unlisted_one_are_named(dataset):
    ids = pq.read_table(dataset / "truth.parquet").column("trace").to_numpy()
    meta = _rewrite_truth(dataset, lambda t: pa.array(ids.clip(0, 1).astype("int32")))  # trace 2 gone
    with pytest.raises(IntegrityError, match=r"has no rows of trace\(s\) \[2\]"):
        integrity.check_trace_ids(dataset, meta)
    extra = ids.copy()
    extra[-3:] = 9  # the last rows of trace 2 as an unlisted trace 9
    meta = _rewrite_truth(dataset, lambda t: pa.array(extra.astype("int32")))
    with pytest.raises(IntegrityError, match=r"has rows of unlisted trace\(s\) \[9\]"):
        integrity.check_trace_ids(dataset, meta)


def test_rows_without_a_trace_id_are_damage(dataset):
    ids = pq.read_table(dataset / "truth.parquet").column("trace").to_pylist()
    ids[5] = None
    meta = _rewrite_truth(dataset, lambda t: pa.array(ids, pa.int32()))
    with pytest.raises(IntegrityError, match="rows without a trace id"):
        integrity.check_trace_ids(dataset, meta)
