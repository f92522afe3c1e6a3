"""Recording format: optional body-frame IMU (specific force + gyroscope) and truth attitude columns."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_import_csv import OMEGA_RADPS, T0_UNIX_S, circle_motion, make_tables, write_rec

from physynth.constants import G0_MPS2
from physynth.errors import RecordingError
from physynth.io import read_dataset, write_dataset
from physynth.io.importers import import_csv


def _body_tables():
    """The circle with a tangent attitude (yaw = phase + 90 deg): body x along the velocity."""
    tables = make_tables()
    t_truth = tables["truth"]["t_s"].to_numpy() - T0_UNIX_S
    yaw = OMEGA_RADPS * t_truth + np.pi / 2
    q = Rotation.from_euler("z", yaw[:, None]).as_quat(scalar_first=True)
    for k, c in enumerate("wxyz"):
        tables["truth"][f"quat_{c}"] = q[:, k]
    imu = tables["imu"]
    t_imu = imu["t_s"].to_numpy() - T0_UNIX_S
    acc_w = circle_motion(t_imu)[2] + np.array([0.0, 0.0, G0_MPS2])
    rot = Rotation.from_euler("z", (OMEGA_RADPS * t_imu + np.pi / 2)[:, None])
    f_b = rot.inv().apply(acc_w)
    imu = imu.drop(columns=["acc_e_mps2", "acc_n_mps2", "acc_u_mps2"])
    for k, c in enumerate("xyz"):
        imu[f"acc_{c}_mps2"] = f_b[:, k]
        imu[f"gyro_{c}_radps"] = [0.0, 0.0, OMEGA_RADPS][k]
    tables["imu"] = imu
    return tables


def test_body_frame_imu_and_attitude_are_imported_and_written_back(tmp_path):
    trace, report = import_csv(write_rec(tmp_path / "rec", _body_tables()))
    assert trace.imu.acc_mps2 is None and trace.imu.frames == ("body-flu",)
    # a body on a circle, x along the velocity: centripetal force along +y (left), gravity along +z
    np.testing.assert_allclose(trace.imu.acc_body_mps2[:, 1], 5.0 * OMEGA_RADPS**2, atol=1e-9)
    np.testing.assert_allclose(trace.imu.acc_body_mps2[:, 2], G0_MPS2, atol=1e-9)
    # body rate from consecutive quaternions (CSV text precision)
    np.testing.assert_allclose(trace.truth.omega_body_radps[:, 2], OMEGA_RADPS, rtol=1e-6)
    write_dataset(tmp_path / "ds", [trace])
    back = read_dataset(tmp_path / "ds")
    assert back.meta["imu_frames"] == ["body-flu"] and back.traces[0].imu.acc_mps2 is None
    np.testing.assert_array_equal(back.traces[0].truth.quat_wxyz, trace.truth.quat_wxyz)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t.__setitem__("truth", t["truth"].drop(columns=["quat_z"])),
     "attitude quaternion columns are incomplete"),
    (lambda t: t["truth"].__setitem__("quat_w", 2.0), "not unit"),
    (lambda t: t.__setitem__("imu", t["imu"].drop(columns=["gyro_y_radps"])), "gyroscope columns are incomplete"),
    (lambda t: t["imu"].__setitem__("acc_z_mps2", 1.0), "gravity included"),
    (lambda t: t["imu"].__setitem__("gyro_x_radps", 57.3), "deg/s"),
])
def test_bad_body_imu_columns_give_one_clear_message(tmp_path, edit, message):
    tables = _body_tables()
    edit(tables)
    with pytest.raises(RecordingError, match=message):
        import_csv(write_rec(tmp_path / "rec", tables))
