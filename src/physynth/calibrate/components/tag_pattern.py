"""The tag antenna pattern: the range bias against the anchor's bearing from the walker's heading.

Part of the ``ranging`` component (fitted and reported always; removed and generated with
``tag_pattern=True``); the fit itself is :func:`physynth.calibrate.tag_pattern.fit_tag_pattern`.
"""

from __future__ import annotations

from .._base import rounded
from ..anchor_channels import Channels
from ..report import ReportBuilder
from ..tag_pattern import fit_tag_pattern


def tag_pattern_step(chan: Channels, rep: ReportBuilder, *, apply: bool) -> tuple[float, ...]:
    """``uwb.tag_pattern_m`` from the LOS rows of every (run, anchor) sequence
    (:func:`physynth.calibrate.tag_pattern.fit_tag_pattern`), reported; zeros when not kept or not
    ``apply``."""
    def sequences():
        for aid, (ra, ga, _) in chan.per_anchor_rows.items():
            start, runs = 0, chan.per_anchor_run[aid]
            for nlos, t, f, v in zip(chan.flags[aid], chan.per_anchor_t[aid], chan.per_anchor_p[aid],
                                     chan.per_anchor_v[aid], strict=True):
                sl = slice(start, start + nlos.size)
                run = int(runs[start]) if nlos.size else 0
                start += nlos.size
                keep = ~nlos
                yield ra[sl][keep], ga[sl][keep], f[keep], t[keep], v[keep], run

    fit = {**fit_tag_pattern(sequences()), "applied": False}
    rep.sections["tag_pattern"] = fit
    if not fit["identifiable"]:
        rep.not_identifiable.append(f"uwb.tag_pattern_m ({fit['why']})")
        return (0.0, 0.0, 0.0, 0.0)
    se = ", ".join(f"{1e3 * x:.1f}" for x in fit["std_error_m"])
    fit["applied"] = bool(apply and fit["kept"])
    coef = [rounded(c, 4) if fit["applied"] else 0.0 for c in fit["coef_m"]]
    status = ("kept and applied" if fit["applied"] else "kept, not generated unless tag_pattern=True"
              if fit["kept"] else "not kept")
    rep.param("uwb.tag_pattern_m", coef, n=fit["n_rows"], summary=True,
              note=(f"range bias vs the anchor's bearing from the heading, cos/sin/cos2/sin2; fitted "
                    f"{', '.join(f'{1e3 * c:.1f}' for c in fit['fitted_coef_m'])} mm (se {se} mm), Wald "
                    f"{fit['wald']:.1f} (threshold {fit['wald_min']}): {status}"))
    return tuple(coef)
