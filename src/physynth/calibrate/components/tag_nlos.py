"""Component ``tag_nlos``: tag-side NLOS, anchors NLOS in the same burst more often than apart
(:mod:`physynth.calibrate.tag_nlos`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...models.uwb import tag_mode_index
from ...scenario import Scenario
from ..anchor_channels import Channels
from ..component import Component
from ..report import ReportBuilder
from ..uwb_fit import MixtureFit


def _mode_arrays(f: MixtureFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (np.array([m.weight for m in f.modes]), np.array([m.mean_m for m in f.modes]),
            np.array([m.std_m for m in f.modes]))


def _near_nlos(f: MixtureFit, x: np.ndarray, nlos: np.ndarray) -> np.ndarray:
    """Rows the mixture calls NLOS whose most likely NLOS mode is the near-LOS one a tag-side episode
    gives the anchor (:func:`physynth.models.uwb.tag_mode_index`)."""
    w, mu, sd = _mode_arrays(f) if f.modes else (np.zeros(0),) * 3
    k = tag_mode_index(w, mu, sd) if f.modes else -1
    if k < 0:
        return np.zeros(x.size, dtype=bool)
    logp = np.log(np.maximum(w, 1e-300)) - np.log(sd) - 0.5 * ((x[:, None] - mu) / sd) ** 2
    return nlos & (logp.argmax(axis=1) == k)


def _near_share(f: MixtureFit) -> float:
    """The fraction of rows a mixture gives its near-LOS NLOS mode (nlos_prob x its weight; 0: none)."""
    if not f.modes:
        return 0.0
    w, mu, sd = _mode_arrays(f)
    k = tag_mode_index(w, mu, sd)
    return float(f.nlos_prob * w[k]) if k >= 0 else 0.0


def tag_nlos_step(chan: Channels, ids: Sequence[str], burst_rate_hz: float, rep: ReportBuilder) -> dict[str, Any]:
    """The tag-side NLOS fraction from the anchors' NLOS rows burst by burst
    (:func:`physynth.calibrate.tag_nlos.fit_tag_nlos`), reported."""
    from ..tag_nlos import fit_tag_nlos

    per_run: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for k, aid in enumerate(ids):
        if aid not in chan.per_anchor_rows:
            continue
        ra, f, start = chan.per_anchor_rows[aid][0], chan.mix[aid], 0
        runs = chan.per_anchor_run[aid]
        for nlos, t in zip(chan.flags[aid], chan.per_anchor_t.get(aid, []), strict=False):
            x = ra[start:start + nlos.size]
            run = int(runs[start]) if nlos.size else -1
            start += nlos.size
            per_run.setdefault(run, []).append((t, np.full(t.size, k), _near_nlos(f, x, nlos)))
    runs = [tuple(np.concatenate([p[i] for p in parts]) for i in range(3)) for parts in per_run.values()]
    fit = fit_tag_nlos(runs, len(ids), 1.0 / burst_rate_hz, np.array([_near_share(chan.mix[a]) for a in ids]))
    fit["applied"] = bool(fit["identifiable"])
    rep.sections["tag_nlos"] = fit
    if fit["identifiable"]:
        rep.param("uwb.tag_nlos_prob", fit["prob"], n=fit["n_bursts"], summary=True,
                  note="anchors NLOS in the same burst more often than apart (pairs of anchors pooled)")
    else:
        rep.not_identifiable.append(f"uwb.tag_nlos_prob ({fit['why']})")
    return fit


def without_tag_nlos(scn: Scenario, report: dict[str, Any]) -> Scenario:  # noqa: ARG001
    """``scn`` with no tag-side NLOS (its NLOS time all per anchor, as before the tag-side process)."""
    return scn.model_copy(update={"uwb": scn.uwb.model_copy(update={"tag_nlos_prob": 0.0})})


COMPONENT = Component(
    without=without_tag_nlos,
    name="tag_nlos", needs=("ranging", "timing"), data="each anchor's NLOS rows burst by burst",
    fits="uwb.tag_nlos_prob",
    fit=lambda ctx: tag_nlos_step(ctx.fitted["ranging"].channels, ctx.inputs.anchor_ids,
                                  ctx.fitted["timing"].burst_rate_hz, ctx.report))
