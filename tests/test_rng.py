"""component_rng: the state numpy's own SeedSequence(root, spawn_key=(i, component)) gives."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from physynth.rng import COMPONENT_ID, component_rng


def test_component_rng_is_numpy_seed_sequence_state_exactly():
    roots = [0, 1, 2026, 2**32 - 1, 2**32, 2**64 + 5, 2**128 - 1, 2**128, 2**200 + 12345, np.int64(9)]
    for root, i, (name, cid) in itertools.product(roots, [0, 1, 19, 2**32 - 1, 2**32, 2**40 + 1], COMPONENT_ID.items()):
        got = component_rng(root, i, name)
        ref = np.random.default_rng(np.random.SeedSequence(int(root), spawn_key=(i, cid)))
        assert got.bit_generator.state == ref.bit_generator.state
        assert got.standard_normal(4).tobytes() == ref.standard_normal(4).tobytes()


def test_component_rng_spawns_and_refuses_like_numpy():
    got = component_rng(5, 3, "uwb").spawn(2)
    ref = np.random.default_rng(np.random.SeedSequence(5, spawn_key=(3, 3))).spawn(2)
    assert [g.random() for g in got] == [r.random() for r in ref]
    assert component_rng(5, 3, "uwb").bit_generator.seed_seq.generate_state(3).tolist() == \
        np.random.SeedSequence(5, spawn_key=(3, 3)).generate_state(3).tolist()
    with pytest.raises(ValueError):
        component_rng(-1, 0, "uwb")
