"""Component ``antenna_sway``: the slow ranging error common to the anchors (a swaying tag antenna),
on a clock of time, distance travelled or motion (:mod:`physynth.calibrate.antenna_sway`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...scenario import Scenario, scenario_from_dict
from .._base import rounded
from ..anchor_channels import Channels
from ..component import Component
from ..report import ReportBuilder


def antenna_sway_step(chan: Channels, rep: ReportBuilder) -> dict[str, Any]:
    """The antenna sway from the LOS rows of every (run, anchor) sequence (those with a trusted truth), their
    range law removed (:func:`physynth.calibrate.antenna_sway.fit_antenna_sway`), reported."""
    from ..antenna_sway import fit_antenna_sway

    def sequences():
        for aid, (ra, ga, _) in chan.per_anchor_rows.items():
            f, start = chan.mix[aid], 0
            for nlos, t, c, h in zip(chan.flags[aid], chan.per_anchor_t.get(aid, []), chan.per_anchor_c.get(aid, []),
                                     chan.per_anchor_h.get(aid, []), strict=False):
                x = ra[start:start + nlos.size] - f.los_centre(ga[start:start + nlos.size])
                trusted = chan.per_anchor_trusted[aid][start:start + nlos.size] if aid in chan.per_anchor_trusted \
                    else True
                start += nlos.size
                keep = ~nlos & np.isfinite(x) & trusted
                yield x[keep], t[keep], c[keep], h[keep]

    fit = fit_antenna_sway(sequences())
    rep.sections["antenna_sway"] = fit
    if fit["identifiable"]:
        note = (f"slow share {fit['slow_share']:.2f} of the LOS variance; each anchor's los_std_m keeps the white "
                f"rest (x {np.sqrt(1.0 - fit['slow_share']):.3f})")
        rep.param("uwb.antenna_sway_std_m", fit["std_m"], n=fit["n_rows"], summary=True, note=note)
        mse = ", ".join(f"{k} {v['mse_m4']:.3g}" for k, v in fit["fits"].items())
        rep.param("uwb.antenna_sway_clock", fit["clock"], n=fit["n_rows"], summary=True,
                  note=f"the clock whose exponential fits the LOS residuals' semivariogram best (mean squared "
                       f"error [m^4]: {mse})")
        if fit["clock"] == "time":
            rep.param("uwb.antenna_sway_tau_s", fit["tau_s"], n=fit["n_rows"], summary=True,
                      note="exponential fit to the LOS residual autocovariance over 0.1-2 s")
        else:
            rep.param("uwb.antenna_sway_length_m", fit["length_m"], n=fit["n_rows"], summary=True,
                      note="distance travelled over which the slow error decorrelates (semivariogram fit)")
            if fit["clock"] == "motion":
                rep.param("uwb.antenna_sway_turn_rad", fit["turn_rad"], n=fit["n_rows"], summary=True,
                          note="angle turned over which the slow error decorrelates (semivariogram fit)")
    else:
        rep.not_identifiable.append(f"uwb.antenna_sway_* ({fit['why']})")
    return fit


def sway_params(sway: dict[str, Any]) -> dict[str, float]:
    """``uwb.antenna_sway_*`` of an identified sway fit (none otherwise: the defaults, no sway)."""
    if not sway.get("identifiable"):
        return {}
    if sway.get("clock") in ("distance", "motion"):
        turn = {"antenna_sway_turn_rad": rounded(sway["turn_rad"], 3)} if sway["clock"] == "motion" else {}
        return {"antenna_sway_std_m": rounded(sway["std_m"], 4), "antenna_sway_clock": sway["clock"],
                "antenna_sway_length_m": rounded(sway["length_m"], 3), **turn}
    return {"antenna_sway_std_m": rounded(sway["std_m"], 4), "antenna_sway_tau_s": rounded(sway["tau_s"], 3)}


def without_sway(scn: Scenario, report: dict[str, Any]) -> Scenario:
    """``scn`` without the sway, each LOS std given back the swaying part (the white twin: the model before
    the sway)."""
    fit = report.get("antenna_sway", {})
    if not fit.get("identifiable"):
        return scn
    d = scn.model_dump(mode="json")
    f = 1.0 / np.sqrt(1.0 - fit["slow_share"])
    d["uwb"]["antenna_sway_std_m"] = 0.0
    d["channel"]["los_std_m"] *= f
    for over in d["channel_per_anchor"].values():
        if over.get("los_std_m"):
            over["los_std_m"] *= f
    return scenario_from_dict(d, "without the antenna sway")


COMPONENT = Component(
    without=without_sway,
    name="antenna_sway", needs=("ranging",),
    data="the LOS rows of every (run, anchor) with a trusted truth, their times, distance travelled and angle turned",
    fits="uwb.antenna_sway_* (each anchor's los_std_m keeps the white rest)",
    fit=lambda ctx: antenna_sway_step(ctx.fitted["ranging"].channels, ctx.report))
