"""The io layer on its own: atomic files, scenario files, and datasets of real and synthetic traces."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import simple_scenario

from physynth.errors import ScenarioError
from physynth.generate import compile_scenario, generate_trace
from physynth.io import read_dataset, read_meta, write_dataset
from physynth.io.atomic import atomic_write_bytes, atomic_write_text, temp_sibling
from physynth.io.scenario_file import list_presets, load_scenario, save_scenario, scenario_to_yaml
from physynth.records import Anchors, Trace, Truth, Uwb


def test_atomic_write_replaces_whole_files_and_cleans_up_on_failure(tmp_path):
    target = tmp_path / "a.txt"
    atomic_write_text(target, "first")
    atomic_write_text(target, "second")
    assert target.read_text() == "second"

    with pytest.raises(TypeError):
        atomic_write_bytes(target, "not bytes")  # fails inside the write
    assert target.read_text() == "second"  # the old content survives
    assert not temp_sibling(target).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_scenario_file_round_trip_for_every_preset(tmp_path):
    for name in list_presets():
        scn = load_scenario(name)
        path = save_scenario(scn, tmp_path / f"{name}.yaml", header="a header\nof two lines")
        assert path.read_text().startswith("# a header\n# of two lines\n")
        assert load_scenario(path) == scn
        assert scenario_to_yaml(load_scenario(path)) == scenario_to_yaml(scn)


def test_scenario_file_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\npath: {kind: spiral}\n")
    with pytest.raises(ScenarioError, match=r"bad.yaml: field path.*kind") as exc:
        load_scenario(bad)
    assert "\n" not in str(exc.value)
    with pytest.raises(ScenarioError, match="not a preset"):
        load_scenario("no-such-preset")


def _real_like_trace() -> Trace:
    """A recording-like trace: no IMU, NLOS unknown, an anchor never heard, a NaN range."""
    t = np.linspace(0.0, 10.0, 81)
    pos = np.stack([t, np.zeros_like(t), np.ones_like(t)], axis=1)
    anchors = Anchors(ids=("3", "5", "9"), names=("A3", "A5", "A9"),
                      pos_enu_m=np.array([[0.0, 5.0, 2.0], [10.0, -5.0, 2.0], [20.0, 0.0, 2.0]]))
    tu = np.array([0.5, 0.6, 1.5, 1.6, 2.5])
    return Trace(truth=Truth(t_s=t, pos_enu_m=pos, vel_enu_mps=np.gradient(pos, t, axis=0)), imu=None,
                 uwb=Uwb(t_s=tu, anchor=np.array([0, 1, 0, 1, 0]), range_m=np.array([5.1, 9.0, np.nan, 8.7, 5.6]),
                         true_range_m=np.full(5, np.nan), nlos=np.zeros(5, bool), burst=np.array([0, 0, 1, 1, 2]),
                         reason=np.array([0, 0, 4, 0, 0], np.int8), nlos_known=False),
                 anchors=anchors, meta={"run": "LOS/Case_1"})


def test_real_and_synthetic_traces_share_one_dataset_format(tmp_path):
    real = _real_like_trace()
    synth = generate_trace(compile_scenario(simple_scenario()), 0, 3)
    path = write_dataset(tmp_path / "ds", [real, synth], meta={"kind": "mixed-test"})
    assert read_meta(path)["n_traces"] == 2
    back = read_dataset(path).traces
    assert back[0].imu is None and back[1].imu is not None
    assert back[0].anchors.ids == ("3", "5", "9") and back[0].anchors.names == ("A3", "A5", "A9")
    assert not back[0].uwb.nlos_known and back[1].uwb.nlos_known
    np.testing.assert_array_equal(back[0].uwb.range_m, real.uwb.range_m)
    np.testing.assert_array_equal(back[0].uwb.reason, real.uwb.reason)
    np.testing.assert_array_equal(back[1].imu.acc_mps2, synth.imu.acc_mps2)
    np.testing.assert_array_equal(back[1].truth.pos_enu_m, synth.truth.pos_enu_m)
    assert back[0].meta.get("run") == "LOS/Case_1"
    # pyarrow reads the files on its own: one UWB row per attempt, anchors by id
    uwb = pq.read_table(Path(path) / "uwb.parquet").to_pandas()
    assert (uwb["trace"] == 0).sum() == 5 and set(uwb.loc[uwb["trace"] == 0, "anchor_id"]) == {"3", "5"}


def test_writer_leaves_no_temporary_folder(tmp_path):
    write_dataset(tmp_path / "ds", [_real_like_trace()])
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]
    assert not any(n.startswith(".") for n in os.listdir(tmp_path / "ds"))


def test_top_level_names_resolve_lazily():
    import subprocess
    import sys

    code = ("import sys, physynth; assert 'scipy' not in sys.modules; "
            "s = physynth.load_scenario('cablecar-ascending'); t = next(physynth.generate_traces(s, n=1, seed=2)); "
            "print(type(t).__name__, physynth.compute_metrics([t]).n_traces)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["Trace", "1"]
    import physynth

    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        physynth.nope  # noqa: B018


def test_declared_column_groups_leave_out_null_columns_and_refuse_undeclared_data(tmp_path):
    from physynth.constants import IMU_BODY_FRAME, IMU_FRAME
    from physynth.errors import DatasetError
    from physynth.io.dataset import DatasetWriter, generated_column_groups

    enu = compile_scenario(load_scenario("cablecar-descending"))
    body = compile_scenario(load_scenario("cablecar-descending").model_copy(
        update={"imu_frames": [IMU_FRAME, IMU_BODY_FRAME]}))
    traces = [generate_trace(enu, i, 3) for i in range(2)]
    with DatasetWriter(tmp_path / "d", compact=True, column_groups=generated_column_groups([IMU_FRAME])) as w:
        for i, t in enumerate(traces):
            w.add(t, index=i)
    names = pq.read_schema(tmp_path / "d" / "imu.parquet").names
    assert names == ["trace", "t_s", "acc_e_mps2", "acc_n_mps2", "acc_u_mps2"]  # no columns of nulls
    for table in ("truth", "imu", "uwb", "anchors"):  # REQUIRED (never null) but for the NLOS flag
        schema = pq.read_schema(tmp_path / "d" / f"{table}.parquet")
        assert [f.name for f in schema if f.nullable] == (["nlos"] if table == "uwb" else [])
    assert pq.read_schema(tmp_path / "d" / "uwb.parquet").field("anchor_id").type == "string"  # not dictionary
    back = read_dataset(tmp_path / "d")
    for a, b in zip(traces, back, strict=True):
        assert b.imu.acc_body_mps2 is None and b.imu.gyro_body_radps is None
        np.testing.assert_allclose(b.imu.acc_mps2, a.imu.acc_mps2, rtol=1e-6, atol=1e-6)  # float32
        np.testing.assert_allclose(b.truth.quat_wxyz, a.truth.quat_wxyz, rtol=0, atol=1.2e-7)  # float32

    with pytest.raises(DatasetError, match="not declared"):  # body IMU data into an ENU-only dataset
        with DatasetWriter(tmp_path / "e", column_groups=generated_column_groups([IMU_FRAME])) as w:
            w.add(generate_trace(body, 0, 3), index=0)
    assert not (tmp_path / "e").exists()  # nothing half-written appears
    with pytest.raises(DatasetError, match="lacks imu columns acc_x_mps2"):  # ENU-only data, body declared
        with DatasetWriter(tmp_path / "f", column_groups=generated_column_groups([IMU_FRAME, IMU_BODY_FRAME])) as w:
            w.add(traces[0], index=0)
    assert not (tmp_path / "f").exists()


def test_generated_columns_use_the_measured_encodings_and_read_back_exactly(tmp_path):
    """The per-column encodings and codecs of a generated dataset (``_column_options``) as written in
    the Parquet metadata, and every value back as generated (float32 columns to float32 precision)."""
    from physynth.constants import IMU_FRAME
    from physynth.io.dataset import DatasetWriter, generated_column_groups

    cs = compile_scenario(load_scenario("cablecar-descending"))
    traces = [generate_trace(cs, i, 5) for i in range(3)]
    with DatasetWriter(tmp_path / "d", compact=True, column_groups=generated_column_groups([IMU_FRAME])) as w:
        for i, t in enumerate(traces):
            w.add(t, index=i)

    def chunks(table):
        md = pq.ParquetFile(tmp_path / "d" / f"{table}.parquet").metadata.row_group(0)
        return {md.column(c).path_in_schema: md.column(c) for c in range(md.num_columns)}

    imu, uwb, truth = chunks("imu"), chunks("uwb"), chunks("truth")
    assert imu["acc_e_mps2"].compression == "UNCOMPRESSED" and "PLAIN" in imu["acc_e_mps2"].encodings
    assert "BYTE_STREAM_SPLIT" not in imu["acc_e_mps2"].encodings
    assert "BYTE_STREAM_SPLIT" in truth["pos_e_m"].encodings and truth["pos_e_m"].compression == "SNAPPY"
    for col in ("burst", "reason"):
        assert "DELTA_BINARY_PACKED" in uwb[col].encodings
    assert "BYTE_STREAM_SPLIT" not in uwb["range_m"].encodings and uwb["range_m"].compression == "SNAPPY"
    assert "RLE_DICTIONARY" in uwb["anchor_id"].encodings
    back = read_dataset(tmp_path / "d")
    for a, b in zip(traces, back, strict=True):
        assert list(b.anchors.ids) == list(a.anchors.ids)
        for col in ("t_s", "range_m", "true_range_m", "anchor", "burst", "reason", "nlos"):
            np.testing.assert_array_equal(getattr(b.uwb, col), getattr(a.uwb, col))
        np.testing.assert_array_equal(b.truth.pos_enu_m, a.truth.pos_enu_m)
        np.testing.assert_array_equal(b.imu.t_s, a.imu.t_s)
        np.testing.assert_array_equal(b.imu.acc_mps2, a.imu.acc_mps2.astype(np.float32))


def test_files_together_appear_together_or_not_at_all(tmp_path):
    """A scenario and its report (physynth calibrate): both renamed into place at the end, or, when the
    block fails after writing one, neither (the old files stay, no temporary is left)."""
    import pytest

    from physynth.io.atomic import files_together

    a, b = tmp_path / "scenario.yaml", tmp_path / "report.json"
    a.write_text("old a")
    with pytest.raises(RuntimeError), files_together([a, b]) as (ta, tb):
        ta.write_text("new a")
        raise RuntimeError("interrupted before the report")
    assert a.read_text() == "old a" and not b.exists() and sorted(p.name for p in tmp_path.iterdir()) == [a.name]
    with files_together([a, b]) as (ta, tb):
        ta.write_text("new a")
        tb.write_text("new b")
        assert a.read_text() == "old a"  # nothing moves before the block ends
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([a.name, b.name])


def test_read_ahead_keeps_order_and_raises_at_the_item_that_failed():
    """The row groups are read one ahead on a reader thread: results in item order, the work done
    off the caller's thread, and a failure raised when the caller reaches that item (not before)."""
    import threading

    from physynth.io.dataset import read_ahead

    threads = set()

    def work(x):
        threads.add(threading.current_thread().name)
        if x == 3:
            raise ValueError("item 3")
        return x * x

    got = []
    with pytest.raises(ValueError, match="item 3"):
        for v in read_ahead(work, range(6)):
            got.append(v)
    assert got == [0, 1, 4] and threads and threading.current_thread().name not in threads
    assert list(read_ahead(work, [])) == [] and list(read_ahead(work, [5])) == [25]
