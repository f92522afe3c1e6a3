"""Channel regimes: named, documented transformations of a scenario (paper section IV.B, Table III).

A regime changes a short, explicit list of parameters and nothing else; :data:`REGIMES` is that list
and :func:`apply_regime` applies it. A change to a ``channel.*`` or ``availability.*`` field applies
to the scenario's default *and* to every per-anchor override that sets the field, so the resolved
value of every anchor is transformed the same way. ``uwb.zones.nlos_prob`` changes every NLOS zone.

- ``nominal``: nothing (the scenario as calibrated).
- ``dense``: every anchor is ranged in every burst (``channel.rate_hz`` = ``uwb.burst_rate_hz``);
  per-burst dropout and outage onset halved. More, fresher measurements of the same quality.
- ``sparse``: half the effective ranging rate (``channel.rate_hz`` x 0.5) and twice the outage onset
  rate (``availability.outage_onset_prob`` x 2). Fewer measurements of the same quality.
- ``degraded``: a worse channel at the same rate: NLOS probability +0.25 (capped at 1) for every anchor
  and zone, LOS noise doubled (``channel.los_std_m`` x 2), dropout doubled.

The same transformations serve ``physynth generate --regime NAME`` and ``physynth study anchors``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from ..errors import PhySynthError
from ..scenario import Scenario, scenario_from_dict, scenario_to_dict


@dataclass(frozen=True, slots=True)
class Change:
    """One documented parameter change: ``op`` in {scale, add, set_burst_rate}, result clipped to ``cap``."""

    field: str  # "channel.<f>", "availability.<f>" or "uwb.zones.nlos_prob"
    op: Literal["scale", "add", "set_burst_rate"]
    value: float = 0.0
    cap: float | None = None

    def describe(self) -> str:
        if self.op == "set_burst_rate":
            return f"{self.field} = uwb.burst_rate_hz"
        what = f"x {self.value:g}" if self.op == "scale" else f"{self.value:+g}"
        return f"{self.field} {what}" + (f" (at most {self.cap:g})" if self.cap is not None else "")

    def apply(self, value: float, burst_rate_hz: float) -> float:
        if self.op == "set_burst_rate":
            return float(burst_rate_hz)
        out = value * self.value if self.op == "scale" else value + self.value
        return min(out, self.cap) if self.cap is not None else out


REGIMES: dict[str, tuple[Change, ...]] = {
    "nominal": (),
    "dense": (
        Change("channel.rate_hz", "set_burst_rate"),
        Change("availability.dropout_prob", "scale", 0.5),
        Change("availability.outage_onset_prob", "scale", 0.5),
    ),
    "sparse": (
        Change("channel.rate_hz", "scale", 0.5),
        Change("availability.outage_onset_prob", "scale", 2.0, cap=1.0),
    ),
    "degraded": (
        Change("channel.nlos_prob", "add", 0.25, cap=1.0),
        Change("uwb.zones.nlos_prob", "add", 0.25, cap=1.0),
        Change("channel.los_std_m", "scale", 2.0),
        Change("availability.dropout_prob", "scale", 2.0, cap=1.0),
    ),
}
"""Every regime and the parameter changes it makes (and nothing else)."""

REGIME_SUMMARY = {
    "nominal": "the scenario as calibrated",
    "dense": "every anchor ranged in every burst, half the dropout and outage onset",
    "sparse": "half the ranging rate, twice the outage onset",
    "degraded": "NLOS probability +0.25 for every anchor and zone, twice the LOS noise and dropout",
}


def describe_regime(name: str) -> dict[str, Any]:
    """JSON-able description of a regime: one-line summary and its changes."""
    return {"summary": REGIME_SUMMARY[check_regime(name)], "changes": [c.describe() for c in REGIMES[name]]}


def check_regime(name: str) -> str:
    if name not in REGIMES:
        raise PhySynthError(f"unknown regime '{name}'; the regimes are {', '.join(REGIMES)}")
    return name


def apply_regime(scn: Scenario, name: str) -> Scenario:
    """The scenario transformed by regime ``name`` (:data:`REGIMES`); ``nominal`` returns it unchanged.

    The result is named ``<scenario>+<regime>`` and records the regime in its provenance.
    """
    changes = REGIMES[check_regime(name)]
    if not changes:
        return scn
    d = scenario_to_dict(scn)
    burst = float(d["uwb"]["burst_rate_hz"])
    for ch in changes:
        section, _, fld = ch.field.partition(".")
        if section == "uwb" and fld == "zones.nlos_prob":
            for z in d["uwb"]["zones"]:
                z["nlos_prob"] = ch.apply(z["nlos_prob"], burst)
            continue
        d[section][fld] = ch.apply(d[section][fld], burst)
        for over in d[f"{section}_per_anchor"].values():
            if over.get(fld) is not None:
                over[fld] = ch.apply(over[fld], burst)
    d["name"] = f"{scn.name}+{name}"
    d["provenance"] = {**d.get("provenance", {}), "regime": {"name": name, **describe_regime(name)}}
    return scenario_from_dict(d, f"{scn.name} with regime {name}")
