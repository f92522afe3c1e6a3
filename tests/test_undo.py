"""The undo journal of a file updated in place (physynth.io.undo): rolled back, the file has its bytes of
when it was opened, whatever was overwritten, appended or cut meanwhile."""

from __future__ import annotations

import numpy as np
import pytest

from physynth.io.undo import _RECORD, UndoFile, roll_back


@pytest.mark.parametrize("seed", range(5))
def test_roll_back_restores_the_bytes_after_random_writes(tmp_path, seed):
    rng = np.random.default_rng(seed)
    f, journal = tmp_path / "f.bin", tmp_path / "f.undo"
    original = rng.integers(0, 256, 5000, dtype=np.uint8).tobytes()
    f.write_bytes(original)
    with UndoFile(f, journal) as fo:
        for _ in range(40):  # overwrites inside, across the end and past it; a cut now and then
            at, n = int(rng.integers(0, 7000)), int(rng.integers(1, 900))
            if rng.random() < 0.1:
                fo.truncate(at)
            else:
                fo.seek(at)
                fo.write(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        assert fo.base == len(original)
    assert f.read_bytes() != original
    roll_back(f, journal)
    assert f.read_bytes() == original and not journal.exists()


def test_only_bytes_of_the_original_file_are_saved(tmp_path):
    f, journal = tmp_path / "f.bin", tmp_path / "f.undo"
    f.write_bytes(b"a" * 100)
    with UndoFile(f, journal) as fo:
        fo.seek(100)
        fo.write(b"b" * 10_000)  # appended: nothing to save
        size_after_append = journal.stat().st_size
        fo.seek(90)
        fo.write(memoryview(np.zeros(5, np.float64)))  # 40 bytes, 10 of them original
    assert journal.stat().st_size == size_after_append + _RECORD.size + 10
    roll_back(f, journal)
    assert f.read_bytes() == b"a" * 100


def test_a_record_cut_short_by_a_kill_is_ignored(tmp_path):
    """A kill while a record is being written leaves it short; the bytes it saves were not overwritten yet."""
    f, journal = tmp_path / "f.bin", tmp_path / "f.undo"
    f.write_bytes(b"0123456789")
    with UndoFile(f, journal) as fo:
        fo.seek(2)
        fo.write(b"xx")
    with open(journal, "ab") as fh:  # the next record: offset 6, 3 bytes, only one of them saved
        fh.write(_RECORD.pack(6, 3) + b"6")
    roll_back(f, journal)
    assert f.read_bytes() == b"0123456789"


def test_an_existing_journal_is_never_overwritten(tmp_path):
    f, journal = tmp_path / "f.bin", tmp_path / "f.undo"
    f.write_bytes(b"data")
    journal.write_bytes(b"another run's journal")
    with pytest.raises(FileExistsError):
        UndoFile(f, journal)
    assert journal.read_bytes() == b"another run's journal" and f.read_bytes() == b"data"
