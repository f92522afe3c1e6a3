"""Importer of BROAD trials (Laidig et al., Data 6(7):72, 2021, doi:10.3390/data6070072, CC BY 4.0).

Loader facts (``data/broad-imu/SOURCE.md``): MATLAB v5 files with ``imu_acc`` (N, 3) [m/s^2, sensor
frame], ``opt_quat`` (N, 4) scalar-first ``wxyz`` orientation of the IMU relative to an ENU-like lab
frame, ``opt_pos`` (N, 3) [m], ``movement`` (N,) false during the rest phases and ``sampling_rate``
[Hz]. Time is the sample index over the sampling rate. Optical dropouts are NaN runs; they are masked
(NaN IMU and truth), never filled.

The world-frame, gravity-free IMU acceleration is

.. math:: a_w = R(q_{wb}) f_b - \\bar g_{rest},

where :math:`\\bar g_{rest}` is the mean world-frame specific force over the rest phases (it absorbs
gravity and the sensor's bias/scale error there: 9.82-9.90 m/s^2 in magnitude, not 9.80665).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy.io import loadmat
from scipy.spatial.transform import Rotation

from ...constants import G0_MPS2
from ...errors import RecordingError
from ...models.attitude import body_rates_from_quat
from ...records import Anchors, Imu, Trace, Truth, Uwb
from ._common import (
    PLAUSIBLE_STEP_S,
    ImportReport,
    ReportBuilder,
    check_gyro_radps,
    check_specific_force,
    check_unit_quaternions,
    checked_window_and_gap,
    velocity_from_position,
)

CITATION = ("D. Laidig, M. Caruso, A. Cereatti, T. Seel, BROAD - A Benchmark for Robust Inertial "
            "Orientation Estimation, Data 6(7):72, 2021, doi:10.3390/data6070072 (CC BY 4.0)")
_KEYS = ("imu_acc", "opt_quat", "opt_pos", "movement", "sampling_rate")
_GYRO_KEY = "imu_gyr"
MAX_LAB_POSITION_M = 50.0
"""An optical position farther than this from the lab origin [m] is taken as a unit mistake (millimetres)."""
REST_GRAVITY_TOLERANCE_MPS2 = 0.5
"""Largest difference between the rest-phase specific force's magnitude and g [m/s^2] (BROAD: 9.82-9.90)."""
MIN_REST_GRAVITY_VERTICAL = 0.95
"""Smallest vertical share g_z / |g| of the rest-phase specific force in the z-up lab frame."""


def import_broad(mat_file: str | os.PathLike, *, velocity_window_s: float = 0.1
                 ) -> tuple[Trace, ImportReport]:
    """Import one BROAD trial (``.mat``) as a Trace with IMU and optical truth, and no UWB.

    Parameters
    ----------
    mat_file
        A BROAD ``data_mat/<trial>.mat`` file.
    velocity_window_s
        Savitzky-Golay window [s] for the truth velocity from the optical position.

    Returns
    -------
    (Trace, ImportReport)
        ``imu.acc_mps2`` (N, 3): world-frame (lab, z up) acceleration with the rest-phase gravity
        vector removed [m/s^2]; ``truth.pos_enu_m`` = ``opt_pos`` [m]; t = index / sampling_rate [s].
        Samples whose ``opt_quat`` or ``opt_pos`` is NaN have NaN IMU acceleration and NaN truth
        position and velocity (counted as ``optical_dropout`` in the report). Empty UWB, no anchors.
        The raw sensor-frame ``imu_acc`` (specific force) and ``imu_gyr`` (angular rate) are kept as
        ``imu.acc_body_mps2`` and ``imu.gyro_body_radps``; the truth carries ``opt_quat`` as its
        attitude and the body rates between consecutive quaternions.
    """
    velocity_window_s, _ = checked_window_and_gap(velocity_window_s)
    path = Path(mat_file)
    mat = _load_trial(path)
    acc_b, gyr_b, quat, pos, movement, rate_hz = _trial_arrays(path, mat)
    moving = movement != 0  # NaN and values other than 0/1 count as moving (never rest), and are counted
    n = acc_b.shape[0]
    rep = ReportBuilder("broad", path)
    masked = _report_dropouts(rep, path.name, acc_b, gyr_b, quat, pos, rate_hz)
    rep.repair(path.name, "movement_not_0_or_1", int(np.count_nonzero(~np.isin(movement, (0.0, 1.0)))))
    _check_units(path, acc_b, pos, rate_hz)

    good = ~masked
    q = check_unit_quaternions(quat[good], path, "opt_quat must hold unit quaternions (w, x, y, z)")
    acc, g_rest, rest = _gravity_free_acc(path, acc_b, q, good, moving)
    truth_pos = np.where(good[:, None], pos, np.nan)
    truth_quat = np.full((n, 4), np.nan)
    truth_quat[good] = q
    t = np.arange(n) / rate_hz
    vel = velocity_from_position(t, truth_pos, window_s=velocity_window_s, max_gap_s=2.0 / rate_hz)
    omega = body_rates_from_quat(t, truth_quat)
    if gyr_b is not None:
        check_gyro_radps(gyr_b, path, _GYRO_KEY, omega_ref=omega)

    meta = _trial_meta(path, mat, rate_hz=rate_hz, g_rest=g_rest, rest=rest, masked=masked,
                       velocity_window_s=velocity_window_s)
    trace = Trace(
        truth=Truth(t_s=t, pos_enu_m=truth_pos, vel_enu_mps=vel, quat_wxyz=truth_quat,
                    omega_body_radps=omega),
        uwb=Uwb(t_s=np.zeros(0), anchor=np.zeros(0, np.int16), range_m=np.zeros(0)),
        anchors=Anchors(ids=(), pos_enu_m=np.zeros((0, 3))),
        imu=Imu(t_s=t, acc_mps2=acc, acc_body_mps2=acc_b, gyro_body_radps=gyr_b),
        meta=meta,
    )
    return trace, rep.build()


def _load_trial(path: Path) -> dict[str, Any]:
    """The variables of a BROAD ``.mat`` file, with the required ones present."""
    if path.is_dir():
        raise RecordingError(f"{path} is a folder; give a BROAD trial file "
                             "(e.g. data_mat/10_undisturbed_slow_translation_A.mat)")
    if not path.is_file():
        raise RecordingError(f"BROAD trial file {path} does not exist")
    try:
        mat = loadmat(path)
    except Exception as exc:  # noqa: BLE001 - scipy raises several types for a bad file
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RecordingError(f"{path}: cannot read MATLAB file: {why}") from None
    missing = [k for k in _KEYS if k not in mat]
    if missing:
        raise RecordingError(f"{path}: missing variable(s) {', '.join(missing)} (not a BROAD trial?)")
    return mat


def _trial_arrays(path: Path, mat: dict[str, Any]
                  ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray, np.ndarray, float]:
    """``(imu_acc, imu_gyr or None, opt_quat, opt_pos, movement, sampling_rate)`` with checked shapes; the IMU
    arrays with NaN for infinities (counted with the NaN samples)."""
    acc_b = _finite_or_nan(_numbers(path, mat, "imu_acc"))
    gyr_b = _finite_or_nan(_numbers(path, mat, _GYRO_KEY)) if _GYRO_KEY in mat else None
    quat = _numbers(path, mat, "opt_quat")
    pos = _numbers(path, mat, "opt_pos")
    moving = _numbers(path, mat, "movement").reshape(-1)
    rate = _numbers(path, mat, "sampling_rate").reshape(-1)
    if rate.size != 1:
        raise RecordingError(f"{path}: sampling_rate has {rate.size} values, expected one number [Hz]")
    rate_hz = float(rate[0])
    n = acc_b.shape[0]
    for name, arr, width in (("imu_acc", acc_b, 3), ("opt_quat", quat, 4), ("opt_pos", pos, 3),
                             (_GYRO_KEY, acc_b if gyr_b is None else gyr_b, 3)):
        if arr.ndim != 2 or arr.shape != (n, width):
            raise RecordingError(f"{path}: {name} has shape {arr.shape}, expected ({n}, {width})")
    if moving.shape != (n,):
        raise RecordingError(f"{path}: movement has {moving.size} samples, expected {n}")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise RecordingError(f"{path}: sampling_rate {rate_hz} is not a positive number")
    return acc_b, gyr_b, quat, pos, moving, rate_hz


def _finite_or_nan(arr: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(arr), arr, np.nan)


def _numbers(path: Path, mat: dict[str, Any], name: str) -> np.ndarray:
    """Variable ``name`` as float64; a RecordingError when it holds text, cells or structs, not numbers."""
    arr = np.asarray(mat[name])
    if arr.dtype.kind not in "biuf":  # text ('U'), a cell or struct array ('O', 'V'), complex ('c')
        kind = {"U": "text", "S": "text", "O": "a cell array", "V": "a struct", "c": "complex"}.get(arr.dtype.kind,
                                                                                               str(arr.dtype))
        what = "is not a number" if arr.size <= 1 else "does not hold numbers"
        raise RecordingError(f"{path}: {name} {what} ({kind})")
    return arr.astype(np.float64)


def _report_dropouts(rep: ReportBuilder, name: str, acc_b: np.ndarray, gyr_b: np.ndarray | None, quat: np.ndarray,
                     pos: np.ndarray, rate_hz: float) -> np.ndarray:
    """Count the samples read, the optical dropouts and the NaN (or infinite) accelerometer and gyroscope
    samples outside them; return the optical-dropout mask."""
    n = acc_b.shape[0]
    rep.read(name, n)
    masked = ~np.all(np.isfinite(quat), axis=1) | ~np.all(np.isfinite(pos), axis=1)
    bad_imu = ~np.all(np.isfinite(acc_b), axis=1) & ~masked
    rep.flag(name, "optical_dropout", int(masked.sum()))
    rep.flag(name, "nan_imu", int(bad_imu.sum()))
    if gyr_b is not None:
        rep.flag(name, "nan_gyro", int(np.count_nonzero(~np.all(np.isfinite(gyr_b), axis=1) & ~masked)))
    runs = np.diff(np.concatenate([[0], masked.astype(np.int8), [0]]))
    run_len = np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)
    if run_len.size:
        rep.note(f"{run_len.size} optical NaN run(s), longest {run_len.max()} samples "
                 f"({run_len.max() / rate_hz:.2f} s); IMU and truth masked (NaN) there, not filled")
    rep.kept(name, n)
    return masked


def _check_units(path: Path, acc_b: np.ndarray, pos: np.ndarray, rate_hz: float) -> None:
    """Errors for a sampling rate, accelerometer or optical position that is evidently in another unit."""
    lo, hi = PLAUSIBLE_STEP_S["imu"]
    if not 1.0 / hi <= rate_hz <= 1.0 / lo:
        raise RecordingError(f"{path}: sampling_rate {rate_hz:.4g} is implausible for an IMU in Hz "
                             f"({1.0 / hi:g} to {1.0 / lo:g}); a period in seconds or milliseconds?")
    far = np.abs(pos[np.all(np.isfinite(pos), axis=1)])
    if far.size and float(far.max()) > MAX_LAB_POSITION_M:
        raise RecordingError(f"{path}: opt_pos reaches {far.max():.4g} from the lab origin, implausible for metres "
                             f"in an optical lab (over {MAX_LAB_POSITION_M:g} m); millimetres? convert to metres")


def _gravity_free_acc(path: Path, acc_b: np.ndarray, q: np.ndarray, good: np.ndarray, moving: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame acceleration minus the rest-phase gravity vector (NaN where ``good`` is false).

    ``q`` holds the normalised quaternions of the ``good`` samples. Returns ``(acc, g_rest, rest)``.
    """
    acc_w = np.full((acc_b.shape[0], 3), np.nan)
    acc_w[good] = Rotation.from_quat(q, scalar_first=True).apply(acc_b[good])
    rest = ~moving & np.all(np.isfinite(acc_w), axis=1)
    if rest.sum() < 10:
        raise RecordingError(f"{path}: fewer than 10 rest samples (movement false) with optical data; "
                             "cannot estimate gravity")
    check_specific_force(acc_b[rest], path, "imu_acc")  # at rest: gravity alone, 9.8 in m/s^2 (1 in g)
    g_rest = acc_w[rest].mean(axis=0)
    g = float(np.linalg.norm(g_rest))
    if abs(g - G0_MPS2) > REST_GRAVITY_TOLERANCE_MPS2:
        raise RecordingError(f"{path}: the rest phases (movement false) read a mean specific force of {g:.4g} "
                             f"m/s^2 in the lab frame, not about {G0_MPS2:.2f}: is opt_quat scalar-first (w, x, "
                             "y, z) and the sensor at rest where movement is 0?")
    if g_rest[2] < MIN_REST_GRAVITY_VERTICAL * g:
        raise RecordingError(f"{path}: the rest-phase specific force {np.round(g_rest, 2).tolist()} m/s^2 does "
                             "not point up the lab z axis: is opt_quat scalar-first (w, x, y, z), sensor to lab?")
    return acc_w - g_rest, g_rest, rest


def _trial_meta(path: Path, mat: dict[str, Any], *, rate_hz: float, g_rest: np.ndarray, rest: np.ndarray,
                masked: np.ndarray, velocity_window_s: float) -> dict[str, Any]:
    """``trace.meta`` of a BROAD trial."""
    info = np.asarray(mat.get("info", np.array([""]))).reshape(-1)
    return {
        "source": "broad",
        "run": path.stem,
        "path": str(path.resolve()),
        "citation": CITATION,
        "info": str(info[0]) if info.size else "",
        "time_origin_s": 0.0,
        "time_base": "sample index / sampling_rate (t = 0 at the first sample)",
        "sampling_rate_hz": rate_hz,
        "frame": "optical lab frame (ENU-like, z up) [m]",
        "imu_processing": "world frame R(opt_quat) * imu_acc minus gravity_rest_mps2 (enu-gravity-free)",
        "gravity_rest_mps2": g_rest.tolist(),
        "gravity_rest_norm_mps2": float(np.linalg.norm(g_rest)),
        "n_rest_samples": int(rest.sum()),
        "optical_dropout_samples": int(masked.sum()),
        "truth_velocity": f"Savitzky-Golay derivative of opt_pos (window {velocity_window_s} s, order 2), "
                          "NaN where masked",
        "truth_attitude": "opt_quat (sensor frame -> lab frame, scalar first), normalised; NaN where masked; "
                          "omega_body_radps from consecutive quaternions",
        "imu_body": "imu_acc [m/s^2] and imu_gyr [rad/s] as recorded, in the sensor frame (body-flu columns; the "
                    "sensor's own axes, not necessarily forward-left-up)",
    }
