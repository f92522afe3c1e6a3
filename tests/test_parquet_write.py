"""Generated Parquet tables: their SHA-256 taken while they are written (no second read), row groups of
io.shards.ROW_GROUP_TRACES traces, and the same files with and without the writer thread."""

from __future__ import annotations

import pyarrow.parquet as pq

from physynth.io import integrity
from physynth.io.dataset import DatasetWriter, read_meta
from physynth.io.shards import ROW_GROUP_TRACES
from physynth.workflows import generate_dataset


def test_hashes_taken_while_writing_match_the_files(tmp_path, monkeypatch):
    def no_reading(path):
        raise AssertionError(f"{path} was read again to hash it")

    monkeypatch.setattr(integrity, "file_sha256", no_reading)
    path, _ = generate_dataset("cablecar-descending", 3, tmp_path / "ds", seed=2)
    monkeypatch.undo()
    files = read_meta(path)["files"]
    assert set(files) == {"truth.parquet", "imu.parquet", "uwb.parquet", "anchors.parquet"}
    for name, rec in files.items():
        assert rec["sha256"] == integrity.file_sha256(path / name)
        assert rec["bytes"] == (path / name).stat().st_size
    integrity.check_dataset(path, read_meta(path), hashes=True)


def test_trailing_hash_follows_an_appending_writer(tmp_path):
    import hashlib
    import os

    path = tmp_path / "f.bin"
    chunks = [os.urandom(n) for n in (0, 1, (1 << 20) - 1, 3 << 20, 17)]  # across its 1 MiB reads
    with open(path, "wb", buffering=0) as f:
        h = integrity.TrailingHash(path)
        for c in chunks:
            f.write(c)
            h.update()
            assert h.size == f.tell()
        h.update()  # nothing new
        f.write(b"footer")
    h.close()  # the bytes written after the last update too
    whole = b"".join(chunks) + b"footer"
    assert h.hexdigest() == hashlib.sha256(whole).hexdigest() and h.size == len(whole)


def test_hashes_taken_row_group_by_row_group(tmp_path, monkeypatch):
    seen = []
    update = integrity.TrailingHash.update

    def spy(self):
        update(self)
        seen.append(self.size)

    monkeypatch.setattr(integrity.TrailingHash, "update", spy)
    generate_dataset("cablecar-descending", 2 * ROW_GROUP_TRACES + 1, tmp_path / "ds", seed=2,
                     shard_traces=2 * ROW_GROUP_TRACES + 1)
    assert len(seen) >= 4 * 3  # four tables, two row groups and the footer each
    assert sum(1 for s in seen if s > 0) >= 4 * 2


def test_row_groups_and_the_writer_thread(tmp_path, monkeypatch):
    n = ROW_GROUP_TRACES + 3
    path, _ = generate_dataset("cablecar-descending", n, tmp_path / "ds", seed=2, shard_traces=n)
    md = pq.ParquetFile(path / "truth.parquet").metadata
    assert md.num_row_groups == 2  # ROW_GROUP_TRACES traces, then the 3 others
    traces = pq.ParquetFile(path / "truth.parquet").read_row_group(0).column("trace").to_pylist()
    assert sorted(set(traces)) == list(range(ROW_GROUP_TRACES))
    imu = pq.ParquetFile(path / "imu.parquet").metadata  # cut by Arrow at 1 Mi rows per group as well
    assert imu.num_row_groups == -(-imu.num_rows // (1 << 20)) + 1
    monkeypatch.setattr(DatasetWriter, "write_in_thread", False)  # the same bytes written in the caller's thread
    other, _ = generate_dataset("cablecar-descending", n, tmp_path / "other", seed=2, shard_traces=n)
    records = [{k: {f: r[f] for f in ("rows", "bytes", "sha256")} for k, r in read_meta(p)["files"].items()}
               for p in (path, other)]
    assert records[0] == records[1]


def test_to_numpy_reads_buffers_with_offsets_and_nulls():
    import numpy as np
    import pyarrow as pa

    from physynth.io.tables import to_numpy

    f = pa.chunked_array([pa.array([1.5, None, 3.0], pa.float32()), pa.array([4.0, 5.0], pa.float32())])
    np.testing.assert_array_equal(to_numpy(f, np.float64), [1.5, np.nan, 3.0, 4.0, 5.0])
    b = pa.array([True, None, False, True, True, False, True, False, True, True])[3:]  # an offset inside a byte
    assert to_numpy(b).tolist() == [True, True, False, True, False, True, True]
    assert to_numpy(pa.array([True, None, True]).is_null()).tolist() == [False, True, False]
    i = pa.array(np.arange(10, dtype=np.int16))[4:7]
    assert to_numpy(i).tolist() == [4, 5, 6] and to_numpy(i).dtype == np.int16
    from physynth.io.tables import valid_mask

    mixed = pa.chunked_array([pa.array([None, 2.0])[1:], pa.nulls(2, pa.float64())])
    for col in (f, b, i, pa.nulls(3, pa.bool_()), mixed):
        assert valid_mask(col).tolist() == [v is not None for v in col.to_pylist()]


def test_reading_a_dataset_does_not_import_pandas(tmp_path):
    """pyarrow's to_numpy would import pandas, half a second of every reader's start."""
    import subprocess
    import sys

    path, _ = generate_dataset("cablecar-descending", 1, tmp_path / "ds", seed=2)
    code = ("import sys; from physynth.io.dataset import read_dataset; read_dataset(sys.argv[1]); "
            "print('pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
