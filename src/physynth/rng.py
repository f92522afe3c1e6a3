"""Random streams: one independent stream per (trace index, model component).

Trace ``i`` of a dataset draws from ``SeedSequence(root, spawn_key=(i, COMPONENT_ID[name]))``, so it is
identical whatever the batch size, worker count or generation order (docs/data-and-metrics.md, section 2).
"""

from __future__ import annotations

import numpy as np

COMPONENT_ID = {"path": 0, "motion": 1, "imu": 2, "uwb": 3, "availability": 4, "attitude": 5, "imu_body": 6,
                "jitter": 7, "uwb_sway": 8, "uwb_tag": 9, "site": 100}
"""``site`` (the scenario's ``variation``: anchor layout and path per trace) is 100, the component the
tracking study's site variation has always drawn from, so its traces are those of the same section."""


def new_root_seed() -> int:
    """Fresh OS entropy as an int, to be stored in the dataset metadata when the user gave no seed."""
    return int(np.random.SeedSequence().entropy)


def component_rng(root_seed: int, trace_index: int, component: str) -> np.random.Generator:
    """The generator of one model component of one trace."""
    key = (int(trace_index), COMPONENT_ID[component])
    return np.random.default_rng(np.random.SeedSequence(int(root_seed), spawn_key=key))
