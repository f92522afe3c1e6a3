"""``iter_stored_traces(..., check_alongside=True)``: the integrity check on a thread of its own while the
traces are read; the same traces, its error at the end or instead of a reading error, no thread left."""

from __future__ import annotations

import json
import shutil
import threading
import time

import numpy as np
import pytest

from physynth.errors import DatasetError, IntegrityError
from physynth.io import dataset as ds
from physynth.io import integrity
from physynth.io.dataset import CHECK_THREAD, iter_stored_traces, read_meta
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset

N = 5


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    path, _ = generate_dataset(load_scenario("cablecar-descending"), N, tmp_path_factory.mktemp("alongside") / "ds",
                               seed=5, shard_traces=2)  # three parts: 2, 2 and 1 traces
    return path


@pytest.fixture
def dataset(generated, tmp_path, monkeypatch):
    """A copy of the dataset that a test may damage; hashes checked whatever the environment says."""
    monkeypatch.delenv("PHYSYNTH_SKIP_HASHES", raising=False)
    path = tmp_path / "ds"
    shutil.copytree(generated, path)
    return path


def _check_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith((CHECK_THREAD, "physynth-sha256"))]


def _last_part(path, table: str) -> str:
    parts = integrity.table_records(read_meta(path)["files"], table)
    assert len(parts) == 3, parts  # the damage below falls after the first traces
    return parts[-1]


def _arrays(st) -> dict:
    return {(t, c): v for t in ("truth", "anchors", "imu", "uwb") for c, v in (getattr(st, t) or {}).items()}


def test_same_traces_with_and_without(dataset):
    plain = list(iter_stored_traces(dataset))
    alongside = list(iter_stored_traces(dataset, check_alongside=True))
    assert [st.index for st in plain] == [st.index for st in alongside] == list(range(N))
    for a, b in zip(plain, alongside, strict=True):
        assert a.meta == b.meta
        assert a.anchor_ids() == b.anchor_ids()
        arrays_a, arrays_b = _arrays(a), _arrays(b)
        assert arrays_a.keys() == arrays_b.keys() and arrays_a
        for key, v in arrays_a.items():
            assert v.dtype == arrays_b[key].dtype, key
            np.testing.assert_array_equal(v, arrays_b[key], err_msg=str(key))
        np.testing.assert_array_equal(a.uwb_anchor(dataset), b.uwb_anchor(dataset))
    assert not _check_threads()


def test_traces_come_while_the_check_runs(dataset, monkeypatch):
    """The first trace is yielded before a slow check ends; the check ends before the iterator does."""
    real = integrity.check_dataset
    said: list[str] = []

    def slow(*args, **kwargs):
        time.sleep(1.0)
        result = real(*args, **kwargs)
        said.append("checked")
        return result

    monkeypatch.setattr(integrity, "check_dataset", slow)
    it = iter_stored_traces(dataset, check_alongside=True)
    for _ in it:
        said.append("trace")
    assert said[0] == "trace" and said[-1] == "checked" and said.count("trace") == N
    said.clear()
    for _ in iter_stored_traces(dataset):  # the default: checked first
        said.append("trace")
    assert said == ["checked"] + ["trace"] * N


def test_a_hash_that_disagrees_is_raised_at_the_end(dataset):
    name = _last_part(dataset, "uwb")
    meta_file = dataset / "dataset.json"
    meta = json.loads(meta_file.read_text(encoding="utf-8"))
    meta["files"][name]["sha256"] = "0" * 64  # the file reads, its hash disagrees
    meta_file.write_text(json.dumps(meta), encoding="utf-8")

    seen = []
    with pytest.raises(IntegrityError, match=f"{name} does not match its sha256"):
        for st in iter_stored_traces(dataset, check_alongside=True):
            seen.append(st.index)
    assert seen == list(range(N))  # every trace read (the file is intact), then the check's error

    seen.clear()
    with pytest.raises(IntegrityError, match=f"{name} does not match its sha256"):
        for st in iter_stored_traces(dataset):
            seen.append(st.index)
    assert seen == []  # the default checks before the first trace
    assert not _check_threads()


def test_a_truncated_file_raises_the_integrity_error_not_the_reading_error(dataset):
    name = _last_part(dataset, "truth")
    f = dataset / name
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])

    # reading fails as it opens the table's files (their footers say whether its row groups are in order)
    with pytest.raises(IntegrityError, match=f"{name} has \\d+ bytes, dataset.json records") as raised:
        list(iter_stored_traces(dataset, check_alongside=True))
    assert raised.value.__cause__ is None and raised.value.__suppress_context__
    assert not _check_threads()

    # without the integrity record, the same file fails to read, and that error is raised
    meta = read_meta(dataset)
    del meta["files"]
    with pytest.raises(DatasetError, match=f"cannot read .*{name}") as raised:
        list(iter_stored_traces(dataset, meta, check_alongside=True))
    assert not isinstance(raised.value, IntegrityError)


@pytest.mark.parametrize("how", ["break", "close"])
def test_stopping_early_leaves_no_check_running(dataset, monkeypatch, how):
    real = integrity.check_dataset
    ended = threading.Event()

    def slow(*args, **kwargs):
        time.sleep(0.5)
        try:
            return real(*args, **kwargs)
        finally:
            ended.set()

    monkeypatch.setattr(integrity, "check_dataset", slow)
    if how == "break":
        for st in iter_stored_traces(dataset, check_alongside=True):
            assert st.index == 0
            assert any(name.startswith(CHECK_THREAD) for name in _check_threads())  # named recognisably
            break  # the generator, no longer referenced, is closed here
    else:
        it = iter_stored_traces(dataset, check_alongside=True)
        next(it)
        it.close()
    assert ended.is_set()
    assert not _check_threads()


def test_stopping_early_after_damage_raises_nothing(dataset):
    """A caller that stops early is not told what the check found (it publishes nothing): closing the
    iterator neither raises nor leaves a thread behind."""
    name = _last_part(dataset, "imu")
    meta = read_meta(dataset)
    meta["files"][name]["sha256"] = "0" * 64
    it = iter_stored_traces(dataset, meta, check_alongside=True)
    assert next(it).index == 0
    it.close()
    assert not _check_threads()
    with pytest.raises(IntegrityError, match=name):
        list(iter_stored_traces(dataset, meta, check_alongside=True))


def _no_traces(path, meta):  # what reading a dataset without traces returns: none, and their number
    return 0
    yield


def test_no_traces_is_said_after_the_check(dataset, monkeypatch):
    monkeypatch.setattr(ds, "_stored_traces", _no_traces)
    with pytest.raises(DatasetError, match="holds no traces"):
        list(iter_stored_traces(dataset, check_alongside=True))
    meta = read_meta(dataset)
    meta["files"][_last_part(dataset, "anchors")]["sha256"] = "0" * 64
    with pytest.raises(IntegrityError):
        list(iter_stored_traces(dataset, meta, check_alongside=True))
