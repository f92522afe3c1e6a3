"""Property tests (hypothesis) over scenario validation, recording import and dataset reading, and a
short seeded run of the fuzz campaign (docs/reliability.md).

The property: any input either works, or raises one :class:`~physynth.errors.PhySynthError` whose
message is one line; nothing else escapes, and a damaged dataset is never read as if it were intact.
"""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from physynth import bounds
from physynth.errors import DatasetError, PhySynthError, RecordingError
from physynth.generate import compile_scenario, generate_trace
from physynth.io import read_dataset, write_dataset
from physynth.io.importers import import_csv
from physynth.scenario import scenario_from_dict
from physynth.testing.fuzz import base_scenario, fuzz, key_paths, parent_of, write_base_recording

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

LEAF = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e4, max_value=1e4),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.text(max_size=6),
    st.none(),
    st.booleans(),
    st.lists(st.floats(min_value=-1e3, max_value=1e3), max_size=4),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
PATHS = key_paths(base_scenario())


def one_line(exc: BaseException) -> bool:
    return "\n" not in str(exc) and bool(str(exc).strip())


@SETTINGS
@given(edits=st.lists(st.tuples(st.sampled_from(PATHS), LEAF), min_size=1, max_size=3))
def test_scenario_validation_accepts_or_refuses_in_one_line(edits):
    d = base_scenario()
    for path, value in edits:
        try:
            parent, key = parent_of(d, path)
            parent[key] = copy.deepcopy(value)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit removed this branch
    try:
        scn = scenario_from_dict(d, "hypothesis")
    except PhySynthError as exc:
        assert one_line(exc)
        return
    saved = bounds.MEMORY_BUDGET_BYTES, bounds.OUTPUT_BUDGET_BYTES
    bounds.MEMORY_BUDGET_BYTES = bounds.OUTPUT_BUDGET_BYTES = 20e6
    try:
        bounds.check_budget(scn, 1)
    except PhySynthError as exc:
        assert one_line(exc)
        return
    finally:
        bounds.MEMORY_BUDGET_BYTES, bounds.OUTPUT_BUDGET_BYTES = saved
    trace = generate_trace(compile_scenario(scn), 0, 1)  # an accepted scenario generates
    assert trace.truth.t_s.size >= bounds.MIN_TRUTH_SAMPLES


@pytest.fixture(scope="module")
def base_rec(tmp_path_factory) -> Path:
    return write_base_recording(tmp_path_factory.mktemp("rec") / "rec")


CELL = st.one_of(st.sampled_from(["", "x", "nan", "inf", "-1", "1e400", "1,5", "0x10", " ", "\u00e9", "1.5"]),
                 st.floats(allow_nan=True, allow_infinity=True).map(repr), st.text(max_size=4))


@SETTINGS
@given(table=st.sampled_from(["truth", "uwb", "imu", "anchors"]), data=st.data())
def test_recording_import_accepts_or_refuses_in_one_line(base_rec, tmp_path_factory, table, data):
    rec = tmp_path_factory.mktemp("case") / "rec"
    shutil.copytree(base_rec, rec)
    df = pd.read_csv(rec / f"{table}.csv", dtype=str, keep_default_na=False)
    for _ in range(data.draw(st.integers(1, 4))):
        col = data.draw(st.sampled_from(list(df.columns)))
        row = data.draw(st.integers(0, len(df) - 1))
        df.loc[df.index[row], col] = data.draw(CELL)
    if data.draw(st.booleans()):
        df = df.rename(columns={data.draw(st.sampled_from(list(df.columns))): data.draw(st.text(min_size=1,
                                                                                                 max_size=5))})
    df.to_csv(rec / f"{table}.csv", index=False)
    try:
        trace, report = import_csv(rec)
    except RecordingError as exc:
        assert one_line(exc)
        return
    assert trace.truth.t_s.size >= 2 and report.rows_read


@pytest.fixture(scope="module")
def base_ds(tmp_path_factory) -> Path:
    from physynth.generate import generate_traces

    scn = scenario_from_dict(base_scenario())
    out = tmp_path_factory.mktemp("ds") / "ds"
    write_dataset(out, generate_traces(scn, 2, seed=4), meta={"kind": "synthetic"})
    return out


@SETTINGS
@given(name=st.sampled_from(["truth.parquet", "imu.parquet", "uwb.parquet", "anchors.parquet", "dataset.json"]),
       where=st.floats(0.0, 0.999), op=st.sampled_from(["flip", "truncate"]), bit=st.integers(0, 7))
def test_damaged_dataset_is_refused_naming_the_file(base_ds, tmp_path_factory, name, where, op, bit):
    ds = tmp_path_factory.mktemp("case") / "ds"
    shutil.copytree(base_ds, ds)
    f = ds / name
    data = bytearray(f.read_bytes())
    i = int(where * len(data))
    if op == "flip":
        data[i] ^= 1 << bit
    else:
        data = data[:i]
    f.write_bytes(bytes(data))
    try:
        got = read_dataset(ds)
    except DatasetError as exc:
        assert one_line(exc)
        if name != "dataset.json":
            assert name in str(exc)
        return
    assert name == "dataset.json"  # a table that changed is never read as intact
    want = read_dataset(base_ds)
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a.truth.pos_enu_m, b.truth.pos_enu_m)
        np.testing.assert_array_equal(a.uwb.range_m, b.uwb.range_m)


def test_short_fuzz_run_finds_no_failure(tmp_path):
    camp = fuzz(100, seed=0, timeout_s=10.0, workdir=tmp_path)
    d = camp.to_dict()
    assert d["inputs"] == 100 and camp.failures == 0, d["examples"]
    assert d["outcomes"]["ok"] > 0 and d["outcomes"]["refused"] > 0
    assert set(d["by_kind"]) == {"scenario", "dataset", "recording"}
