"""A small site for the tracking tests: a 40 m walk among four anchors, a few seconds of data."""

from __future__ import annotations

from helpers import simple_scenario

from physynth.scenario import Scenario

ANCHORS = [{"id": "A1", "pos_enu_m": [0, -8, 2]}, {"id": "A2", "pos_enu_m": [40, -8, 0.5]},
           {"id": "A3", "pos_enu_m": [40, 8, 2.5]}, {"id": "A4", "pos_enu_m": [0, 8, 1]}]


def site_scenario(noise_m: float = 0.05, **updates) -> Scenario:
    """Walk from (2, 0, 1) to (38, 3, 1) at 3 m/s past four anchors; ranges at 10 Hz with ``noise_m`` noise."""
    return simple_scenario(**{
        "path.waypoints_enu_m": [[2, 0, 1], [20, 4, 1], [38, 3, 1]],
        "anchors": ANCHORS,
        "uwb.burst_rate_hz": 10.0,
        "channel.rate_hz": 10.0,
        "channel.los_std_m": noise_m,
        **updates,
    })
