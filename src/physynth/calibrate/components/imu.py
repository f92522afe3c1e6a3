"""Component ``imu``: the IMU noise from every recording with IMU samples (the IMU-only ones included)."""

from __future__ import annotations

from ...progress import ProgressCallback
from ...scenario import ImuParams
from ..component import CalibrationContext, Component
from ..inputs import CalibrationInputs
from ..report import ReportBuilder


def fit_imu_step(inp: CalibrationInputs, report: ReportBuilder, progress: ProgressCallback) -> ImuParams:
    """IMU noise from every recording with IMU samples (the IMU-only ones included)."""
    imu_traces = [t for t in inp.traces if t.imu is not None and t.imu.t_s.size > 100] + inp.imu_only
    if not imu_traces:
        report.sections["imu"] = {"note": "no IMU samples in the recordings: IMU parameters are the defaults, "
                                          "not calibrated"}
        report.not_identifiable.append("imu (no IMU data; defaults kept)")
        return ImuParams()
    progress("fitting IMU noise")
    from ..imu_fit import fit_imu

    imf = fit_imu(imu_traces)
    p = imf.params
    from ..imu_only import has_body_imu

    if any(has_body_imu(t) for t in imu_traces):  # fitted by the IMU-only calibration alone
        report.not_identifiable.append("body_imu (the body-frame accelerometer and gyroscope are fitted only when "
                                       "every recording is IMU-only; defaults kept)")
    report.sections["imu"] = imf.diagnostics
    report.param("imu.white_noise_density_mps2_per_sqrt_hz", list(p.white_noise_density_mps2_per_sqrt_hz),
                 n=imf.n_samples, summary=True)
    report.param("imu.bias_rw_mps2_per_sqrt_s", p.bias_rw_mps2_per_sqrt_s, n=imf.n_samples)
    report.param("imu.vibration.fundamental_hz", p.vibration.fundamental_hz, n=imf.n_samples, summary=True)
    report.param("imu.vibration.amplitude_mps2", p.vibration.amplitude_mps2, n=imf.n_samples, summary=True)
    return p


def _fit(ctx: CalibrationContext) -> ImuParams:
    inp = ctx.inputs
    if not any(t.imu is not None and t.imu.t_s.size > 100 for t in inp.traces + inp.imu_only):
        ctx.skip("imu", "no IMU samples in the recordings")
    return fit_imu_step(inp, ctx.report, ctx.progress)


COMPONENT = Component(name="imu", data="IMU samples beside a ground truth (the IMU-only recordings included)",
                      fits="imu (white noise, bias random walk, vibration)", fit=_fit)
