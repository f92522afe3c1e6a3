"""Validation of IMU recordings without UWB: IMU error statistics, real against synthetic.

The errors (IMU minus what the truth says it should read), their reduction trace by trace and their
comparison are :mod:`physynth.validate.imu_errors`; ``report.json`` holds the ``real``,
``synthetic``, ``relative_deviation_pct`` and ``extended`` keys described there. This module builds
the report (:func:`compare_imu`, :func:`validate_imu`) and writes its files (:func:`write_imu_report`).

With ``transfer``, each synthetic trace runs the scenario's IMU models along a real trace's own truth
(its acceleration and attitude), trace i along real trace i mod R, seeded per trace and component;
without it, synthetic traces are generated from the scenario (its own path, motion and attitude).
"""

from __future__ import annotations

import base64
import datetime as _dt
import json
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .. import __version__
from .._json import jsonable
from ..calibrate.imu_fit import (
    filled_truth_acceleration,
    has_truth_rotation,
    imu_along_truth,
    smoothed_body_rate,
)
from ..calibrate.imu_only import has_body_imu
from ..errors import OutputExistsError, PhySynthError
from ..generate import compile_scenario, generate_traces
from ..io.atomic import atomic_write_bytes, atomic_write_text
from ..models.imu import simulate_body_imu
from ..records import Imu, Trace
from ..rng import component_rng, new_root_seed
from ..scenario import Scenario, scenario_to_dict
from .imu_errors import ALLAN_TAUS_S as ALLAN_TAUS_S  # the error statistics, a floor below: named here as before
from .imu_errors import CUTOFF_HZ, ERRORS, ImuErrorAccumulator, imu_error_comparison


def is_imu_only(traces: Sequence[Trace]) -> bool:
    """True when no trace has anchors or UWB rows and every trace has IMU samples."""
    return bool(traces) and all(len(t.anchors) == 0 and len(t.uwb) == 0 and t.imu is not None for t in traces)


def _summary(traces: Iterable[Trace]) -> dict[str, dict[str, Any]]:
    """Per error kind: std per axis, pooled Welch PSD, mean Allan deviation at ALLAN_TAUS_S."""
    acc = ImuErrorAccumulator()
    for tr in traces:  # a few traces, each vectorised
        acc.add(tr)
    return acc.finish()


def _along_truth(real: Trace, scn: Scenario, root: int, index: int) -> Trace:
    """The scenario's IMU models run along a real trace's own truth (acceleration, attitude): the ENU
    model reads the truth band it was calibrated against (``imu.truth_cutoff_hz``) and its lever arm
    acts along the truth's rotation; the body-frame model reads the same band."""
    fc = scn.imu.truth_cutoff_hz or CUTOFF_HZ  # the band both models were fitted against
    tg, filled = filled_truth_acceleration(real, fc)
    enu = imu_along_truth(real, scn.imu, rng=component_rng(root, index, "imu"), input_cutoff_hz=fc,
                          truth_input=(tg, filled))
    imu = Imu(t_s=enu.t_s, acc_mps2=enu.acc_mps2)
    if has_body_imu(real) and "body-flu" in scn.imu_frames and has_truth_rotation(real):
        w = smoothed_body_rate(real, tg, fc)
        q = real.truth.quat_wxyz
        ok = np.all(np.isfinite(q), axis=1)
        k = np.clip(np.searchsorted(real.truth.t_s[ok], tg), 0, int(ok.sum()) - 1)
        rot = Rotation.from_quat(q[ok][k], scalar_first=True)  # nearest valid attitude (masked spans held)
        params = scn.body_imu.model_copy(update={"rate_hz": scn.imu.rate_hz})
        t_b, acc_b, gyro_b = simulate_body_imu(tg, filled, rot, w, params, rng=component_rng(root, index, "imu_body"))
        n = min(t_b.size, enu.t_s.size)
        imu = Imu(t_s=enu.t_s[:n], acc_mps2=enu.acc_mps2[:n], acc_body_mps2=acc_b[:n], gyro_body_radps=gyro_b[:n])
    return Trace(truth=real.truth, uwb=real.uwb, anchors=real.anchors, imu=imu, meta={"source": "physynth"})


@dataclass(frozen=True, slots=True)
class ImuValidationReport:
    """IMU error statistics of real and synthetic traces (keys in :mod:`physynth.validate.imu_errors`)."""

    real: dict[str, Any]
    synthetic: dict[str, Any]
    relative_deviation_pct: dict[str, Any]
    extended: dict[str, Any]
    inputs: dict[str, Any] = field(default_factory=dict)
    transfer: dict[str, Any] | None = None
    series: dict[str, dict[str, Any]] | None = None
    """Per error kind and side (``real``, ``synthetic``): the pooled Welch PSD (``f`` (F,), ``psd`` (F, 3)) and
    the Allan deviation at :data:`ALLAN_TAUS_S` (``adev`` (4, 3) or None), which the figures are drawn from;
    not in report.json (a report read back has no figures)."""

    def to_dict(self) -> dict[str, Any]:
        return jsonable({"kind": "imu", "generator": {"name": "physynth", "version": __version__},  # io.safety marker
                         "real": self.real, "synthetic": self.synthetic,
                         "relative_deviation_pct": self.relative_deviation_pct, "extended": self.extended,
                         "inputs": self.inputs, "transfer": self.transfer})


def compare_imu(real: Sequence[Trace], synthetic: Sequence[Trace], *, inputs: dict[str, Any] | None = None,
                transfer: dict[str, Any] | None = None) -> ImuValidationReport:
    """IMU error statistics of both sides and their distances (:mod:`physynth.validate.imu_errors`)."""
    rs, ss = _summary(real), _summary(synthetic)
    if "imu" not in rs and "gyro" not in rs:
        raise PhySynthError("the real dataset has no IMU samples with valid truth: nothing to compare")
    if not set(rs) & set(ss):
        raise PhySynthError(f"the synthetic traces have no IMU error of a kind the real dataset has "
                            f"(real: {', '.join(sorted(rs))}; synthetic: {', '.join(sorted(ss)) or 'none'})")
    out_r, out_s, dev, ext = imu_error_comparison(rs, ss)
    return ImuValidationReport(real=out_r, synthetic=out_s, relative_deviation_pct=dev, extended=ext,
                               inputs={**(inputs or {}), "n_traces": {"real": len(real), "synthetic": len(synthetic)},
                                       "truth_cutoff_hz": CUTOFF_HZ, "physynth_version": __version__,
                                       "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")},
                               transfer=transfer,
                               series={k: {"real": rs[k], "synthetic": ss[k]} for k in ERRORS if k in rs and k in ss})


def validate_imu(real: Sequence[Trace], *, scenario: Scenario | None = None, synthetic: Sequence[Trace] | None = None,
                 n: int = 10, seed: int | None = None, transfer: bool = False, inputs: dict[str, Any] | None = None,
                 progress: Callable[[str, int, int], None] | None = None) -> ImuValidationReport:
    """Validate IMU-only real traces against a synthetic dataset or traces from a scenario."""
    inputs = dict(inputs or {})
    if synthetic is not None:
        return compare_imu(real, list(synthetic), inputs=inputs)
    if scenario is None:
        raise PhySynthError("give a synthetic dataset or a scenario")
    root = new_root_seed() if seed is None else int(seed)
    synth: list[Trace] = []
    if transfer:
        for i in range(n):  # n traces, each vectorised
            synth.append(_along_truth(real[i % len(real)], scenario, root, i))
            if progress is not None:
                progress("running the IMU model along the real truth", i + 1, n)
    else:
        for i, tr in enumerate(generate_traces(compile_scenario(scenario), n, seed=root)):
            synth.append(tr)
            if progress is not None:
                progress("generating synthetic traces", i + 1, n)
    inputs["synthetic"] = {**(inputs.get("synthetic") or {}), "scenario_name": scenario.name, "n_traces": int(n),
                           "root_seed": root, "transfer": bool(transfer), "scenario_config": scenario_to_dict(scenario)}
    tr_info = ({"what": "each synthetic trace runs the scenario's IMU models along a real trace's truth "
                        "(acceleration, attitude); trace i along real trace i mod R",
                "model_truth_cutoff_hz": float(scenario.imu.truth_cutoff_hz or CUTOFF_HZ)} if transfer else None)
    return compare_imu(real, synth, inputs=inputs, transfer=tr_info)


def write_imu_report(report: ImuValidationReport, out: str | os.PathLike, *, overwrite: bool = False,
                     figures: bool = True) -> list[Path]:
    """report.json, report.md and report.html (inputs, the real data's citation, the error and Allan
    ratio tables, the transfer, the figures) and, when the synthetic side was generated from a scenario,
    that scenario as ``scenario.yaml``, into folder ``out``; each file written atomically.

    ``figures``: ``imu_error_psd.png`` and ``imu_error_allan.png``, real against synthetic per error kind
    and axis (:func:`physynth.validate.figures.render_imu_figures`; needs matplotlib), also embedded in
    report.html. A report without its series (read back from report.json) gets none."""
    import html as _html

    from ..io.scenario_file import mapping_to_yaml
    from .figures import IMU_FIGURES, render_imu_figures

    out = Path(out)
    if (out / "report.json").exists() and not overwrite:
        raise OutputExistsError(out, "holds a report")
    pngs = render_imu_figures(report.series) if figures and report.series else {}  # before touching the folder
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PhySynthError(f"cannot create {out}: {exc.strerror}") from None
    d = report.to_dict()
    lines, tables = imu_inputs_lines(d), _imu_tables(d)
    md = ["# IMU validation", "", *[f"- {x}" for x in lines], ""]
    page = ["<!doctype html><meta charset='utf-8'><title>IMU validation</title><h1>IMU validation</h1><ul>",
            *[f"<li>{_html.escape(x)}</li>" for x in lines], "</ul>"]
    for title, headers, rows in tables:
        md += [f"## {title}", "", "| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        md += ["| " + " | ".join(r) + " |" for r in rows] + [""]
        page += [f"<h2>{_html.escape(title)}</h2><table border=1><tr>"
                 + "".join(f"<th>{_html.escape(h)}</th>" for h in headers) + "</tr>"]
        page += ["<tr>" + "".join(f"<td>{_html.escape(c)}</td>" for c in r) + "</tr>" for r in rows] + ["</table>"]
    if pngs:
        md += ["## Figures", ""] + [f"![{name}]({name}.png)\n\n{IMU_FIGURES[name]}\n" for name in pngs]
        page += ["<h2>Figures</h2>"] + [
            f'<figure id="fig-{name}"><img alt="{name}" src="data:image/png;base64,'
            f'{base64.b64encode(png).decode("ascii")}"><figcaption>{_html.escape(IMU_FIGURES[name])}</figcaption>'
            "</figure>" for name, png in pngs.items()]
    files = {"report.json": json.dumps(d, indent=1), "report.md": "\n".join(md).rstrip() + "\n",
             "report.html": "\n".join(page) + "\n"}
    config = (d["inputs"].get("synthetic") or {}).get("scenario_config")
    if config:
        files["scenario.yaml"] = ("# scenario the synthetic traces of this report were generated from\n"
                                  + mapping_to_yaml(config))
    written = []
    for stale in IMU_FIGURES:  # a figure of an earlier report that this one does not have
        if stale not in pngs and (out / f"{stale}.png").exists():
            (out / f"{stale}.png").unlink()
    for name, png in pngs.items():
        atomic_write_bytes(out / f"{name}.png", png)
        written.append(out / f"{name}.png")
    for name, text in files.items():
        atomic_write_text(out / name, text)
        written.append(out / name)
    return written


def imu_inputs_lines(d: dict[str, Any]) -> list[str]:
    """The provenance lines of an IMU-only report (``d`` its ``to_dict``): real and synthetic side,
    version, the transfer and the real data's citation."""
    inp = d.get("inputs", {})
    real, syn, n = inp.get("real", {}), inp.get("synthetic") or {}, inp.get("n_traces", {})
    lines = [f"Real: {real.get('path', '?')} ({n.get('real', '?')} trace(s), IMU-only; IMU frames "
             f"{', '.join(real.get('imu_frames') or []) or '?'})"]
    if "scenario_name" in syn:
        lines.append(f"Synthetic: {n.get('synthetic', '?')} trace(s) from scenario '{syn['scenario_name']}'"
                     + (f" ({syn['scenario']})" if syn.get("scenario") else "")
                     + f", root seed {syn.get('root_seed')}"
                     + (", transferred: along the real truth" if syn.get("transfer") else ""))
    else:
        lines.append(f"Synthetic: {syn.get('path', '?')} ({n.get('synthetic', '?')} trace(s))")
    lines.append(f"Truth low-passed at {inp.get('truth_cutoff_hz', '?')} Hz; physynth "
                 f"{inp.get('physynth_version', '?')}; created {inp.get('created_utc', '?')}")
    if d.get("transfer"):
        lines.append(f"Transfer: {d['transfer'].get('what')}.")
    if "broad" in str(real.get("source") or "").lower():
        from ..io.importers.broad import CITATION

        lines.append(f"Real data: {CITATION}.")
    return lines


def _imu_tables(d: dict[str, Any]) -> list[tuple[str, tuple[str, ...], list[tuple[str, ...]]]]:
    """(title, headers, rows) of the error std table and of one Allan ratio table per error kind."""
    def fmt(v: Any, digits: int = 4) -> str:
        return " / ".join("-" if x is None else f"{x:.{digits}g}" for x in v) if v is not None else "-"

    rows, allan = [], []
    for kind, unit in ERRORS.items():
        key = f"{kind}_error_std_{unit}"
        if d["real"].get(key) is None or d["synthetic"].get(key) is None:
            continue
        lsd = (d["extended"].get(f"{kind}_log_spectral_distance_db") or {}).get("per_axis")
        rows.append((key, fmt(d["real"][key]), fmt(d["synthetic"][key]), fmt(d["relative_deviation_pct"][key], 3),
                     fmt(lsd, 3)))
        ar = d["extended"].get(f"{kind}_allan_ratio") or {}
        allan += [(f"{kind}_allan_ratio", f"{tau:g}", fmt(r, 3))
                  for tau, r in zip(ar.get("tau_s", []), ar.get("ratio", []), strict=False)]
    tables = [("IMU error std, real vs synthetic", ("error std", "real", "synthetic", "deviation [%]",
                                                    "log-spectral distance [dB]"), rows)]
    if allan:
        tables.append(("Allan deviation of the error, synthetic / real per axis",
                       ("error", "tau [s]", "ratio"), allan))
    return tables
