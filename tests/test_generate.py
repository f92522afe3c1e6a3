"""Determinism, batch independence, path/motion properties and the dataset round trip."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from helpers import simple_scenario

from physynth.errors import DatasetError, OutputExistsError
from physynth.generate import compile_scenario, generate_trace, generate_traces
from physynth.io import DatasetWriter, read_dataset
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


@pytest.fixture(scope="module")
def preset():
    return compile_scenario(load_scenario("cablecar-descending"))


def _f32(x):
    return np.asarray(x).astype(np.float32).astype(np.float64)


def _assert_same(a, b, stored=False):
    """Same trace; ``stored``: ``a`` was read back from a generated dataset (IMU, velocity as float32)."""
    np.testing.assert_array_equal(a.truth.t_s, b.truth.t_s)
    np.testing.assert_array_equal(a.truth.pos_enu_m, b.truth.pos_enu_m)
    f = _f32 if stored else np.asarray
    np.testing.assert_array_equal(a.imu.acc_mps2, f(b.imu.acc_mps2))
    np.testing.assert_array_equal(a.truth.vel_enu_mps, f(b.truth.vel_enu_mps))
    for f in ("t_s", "anchor", "range_m", "true_range_m", "nlos", "burst", "reason"):
        np.testing.assert_array_equal(getattr(a.uwb, f), getattr(b.uwb, f))


def test_same_seed_same_trace_other_seed_other_trace(preset):
    a, b = generate_trace(preset, 0, 42), generate_trace(preset, 0, 42)
    _assert_same(a, b)
    c = generate_trace(preset, 0, 43)
    assert not np.array_equal(a.imu.acc_mps2[:100], c.imu.acc_mps2[:100])


def test_trace_i_does_not_depend_on_batch_size_or_order(preset):
    five = list(generate_traces(preset, 5, seed=9))
    late = list(generate_traces(preset, 3, seed=9, start=3))
    _assert_same(five[3], late[0])
    _assert_same(five[4], late[1])
    # traces of one dataset differ from each other
    assert five[0].duration_s != five[1].duration_s


def test_run_to_run_perturbation_keeps_the_stations(preset):
    trs = list(generate_traces(preset, 6, seed=3))
    starts = np.array([t.truth.pos_enu_m[0] for t in trs])
    ends = np.array([t.truth.pos_enu_m[-1] for t in trs])
    np.testing.assert_allclose(starts - starts[0], 0.0, atol=1e-6)
    np.testing.assert_allclose(ends - ends[0], 0.0, atol=1e-3)
    mids = np.array([t.truth.pos_enu_m[len(t.truth.t_s) // 2] for t in trs])
    assert np.ptp(mids[:, 2]) > 0.1  # sag varies between runs
    lat = np.array([t.meta["lateral_offset_m"] for t in trs])
    assert np.all(np.abs(lat) < 5 * 2.0)


def test_speed_spread_and_duration_are_uniform_within_bounds(preset):
    trs = [generate_trace(preset, i, 5) for i in range(40)]
    sf = np.array([t.meta["speed_factor"] for t in trs])
    lf = np.array([t.meta["length_factor"] for t in trs])
    assert np.all((sf >= 0.88) & (sf <= 1.12)) and np.all((lf >= 0.95) & (lf <= 1.05))
    assert np.ptp(sf) > 0.12  # spread actually used
    d = np.array([t.duration_s for t in trs])
    # duration scales with length / speed
    ratio = d / (lf / sf)
    np.testing.assert_allclose(ratio / ratio[0], 1.0, rtol=2e-3)


def test_travel_starts_and_ends_at_rest_and_length_matches(preset):
    t = generate_trace(preset, 0, 1)
    speed = np.linalg.norm(t.truth.vel_enu_mps, axis=1)
    assert speed[0] < 0.05 and speed[-1] < 0.2
    path_len = np.linalg.norm(np.diff(t.truth.pos_enu_m, axis=0), axis=1).sum()
    assert path_len == pytest.approx(710.2, rel=0.01)
    drop = t.truth.pos_enu_m[0, 2] - t.truth.pos_enu_m[-1, 2]
    assert drop == pytest.approx(342.0, abs=1.0)


def test_ascending_preset_travels_the_other_way():
    asc = generate_trace(compile_scenario(load_scenario("cablecar-ascending")), 0, 1)
    assert asc.truth.pos_enu_m[-1, 2] - asc.truth.pos_enu_m[0, 2] == pytest.approx(342.0, abs=1.0)


def test_dataset_round_trip(tmp_path):
    scn = load_scenario("cablecar-descending")
    path, root = generate_dataset(scn, 3, tmp_path / "ds", seed=11)
    assert root == 11
    back = read_dataset(path)
    cs = compile_scenario(scn)
    for i, tr in enumerate(back.traces):
        _assert_same(tr, generate_trace(cs, i, 11), stored=True)
        assert tr.anchors.ids == cs.anchors.ids
        np.testing.assert_array_equal(tr.anchors.pos_enu_m, cs.anchors.pos_enu_m)
        assert tr.uwb.nlos_known
    meta = json.loads((path / "dataset.json").read_text())
    assert meta["root_seed"] == 11 and meta["n_traces"] == 3
    assert meta["imu_frame"] == "enu-gravity-free"
    assert meta["scenario"]["name"] == "cablecar-descending"
    assert [t["spawn_key"] for t in meta["traces"]] == [[0], [1], [2]]
    # the tables are real Parquet files with a trace column, readable by pyarrow itself
    for name in ("truth", "imu", "uwb", "anchors"):
        table = pq.read_table(path / f"{name}.parquet")
        assert sorted(set(table.column("trace").to_pylist())) == [0, 1, 2]
    uwb = pq.read_table(path / "uwb.parquet").to_pandas()
    assert uwb["range_m"].isna().any() and (uwb.loc[uwb["range_m"].isna(), "reason"] != 0).all()


def test_refuses_to_overwrite_and_overwrites_when_asked(tmp_path):
    scn = simple_scenario()
    generate_dataset(scn, 1, tmp_path / "ds", seed=1)
    with pytest.raises(OutputExistsError, match="already exists"):
        generate_dataset(scn, 1, tmp_path / "ds", seed=2)
    generate_dataset(scn, 2, tmp_path / "ds", seed=2, overwrite=True)
    assert len(read_dataset(tmp_path / "ds")) == 2


def test_interrupted_write_leaves_nothing_that_looks_complete(tmp_path):
    scn = compile_scenario(simple_scenario())
    with pytest.raises(RuntimeError):
        with DatasetWriter(tmp_path / "ds") as w:
            w.add(generate_trace(scn, 0, 1))
            raise RuntimeError("killed")
    assert not (tmp_path / "ds").exists()
    assert list(tmp_path.iterdir()) == []


def test_reading_a_broken_dataset_gives_one_clear_error(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        read_dataset(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no dataset.json"):
        read_dataset(tmp_path / "empty")
    generate_dataset(simple_scenario(), 1, tmp_path / "ds", seed=1)
    (tmp_path / "ds" / "uwb.parquet").write_bytes(b"garbage")
    with pytest.raises(DatasetError, match="damaged: uwb.parquet has 7 bytes"):
        read_dataset(tmp_path / "ds")
    (tmp_path / "ds" / "uwb.parquet").unlink()
    with pytest.raises(DatasetError, match="uwb.parquet is missing"):
        read_dataset(tmp_path / "ds")


def test_polynomial_rows_of_different_degree():
    from physynth.models.path import compile_path
    from physynth.scenario import PathParams

    geo = compile_path(PathParams(kind="polynomial", length_m=100.0,
                                  coeffs_enu_m=[[0.0, 100.0], [0.0, 0.0, 5.0], [10.0, -2.0]]))
    p, d1, _ = geo.evaluate([0.0, 50.0, 100.0])
    np.testing.assert_allclose(p[:, 0], [0.0, 50.0, 100.0])
    np.testing.assert_allclose(p[:, 1], [0.0, 1.25, 5.0])
    np.testing.assert_allclose(d1[1], [1.0, 0.05, -0.02])


def test_bursts_are_clock_locked_with_independent_jitter():
    from physynth.models.uwb import burst_times

    t = burst_times(0.0, 2000.0, 20.0, 0.002, 0.0, rng=np.random.default_rng(1))
    k = np.round((t - t[0]) / 0.05)
    resid = t - t[0] - 0.05 * k
    # no drift: the deviation from the locked grid stays at the jitter level over 40,000 bursts
    assert np.abs(resid - resid.mean()).max() < 6 * 0.002
    assert np.std(np.diff(t)) == pytest.approx(0.002 * np.sqrt(2), rel=0.05)


def test_negative_counts_are_refused_at_the_call(preset):
    with pytest.raises(ValueError, match=r"^n must be >= 0 \(the number of traces\), got -1$"):
        generate_traces(preset, n=-1)  # not a silent empty iterator
    with pytest.raises(ValueError, match=r"^start must be >= 0"):
        generate_traces(preset, n=1, start=-2)
    assert list(generate_traces(preset, n=0, seed=1)) == []
    assert len(list(generate_traces(preset, n=2, seed=1))) == 2
