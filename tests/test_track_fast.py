"""The vectorised classical trackers against their first, per-step versions (tests/track_reference.py).

- ``ekf``: the jumps between update steps (closed-form F(T), Q(T) and IMU control) and the vectorised
  fill of the steps in between reproduce the per-step recursion to rounding (1e-9 relative), with the
  same gating and resets, on a generated cable-car trace (IMU-driven), on the site walk (constant
  velocity) and on a real Hanyang run.
- ``ls``: every step minimises the same robust cost. Where that minimum is well defined (a walk among
  anchors at two heights) both give the same positions, to the reference's tolerance; where it is
  not (the cable car's anchors along the cable, the Hanyang anchors in a 2 m box 50 m away: a ring of
  near-solutions; anchors in one plane: a mirror fix), the reference's block-wide ``least_squares``
  stops early and the new solver reaches a lower cost, or another of the near-solutions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from track_helpers import site_scenario
from track_reference import ReferenceEkfTracker, ReferenceLsTracker
from track_reference import multilaterate as reference_multilaterate

from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.track.inputs import track_input
from physynth.track.trackers.ekf import EkfTracker
from physynth.track.trackers.ls import LsTracker, cost_terms, multilaterate

RUN = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "hanyang-uwb" / "Dynamic_measurements"
       / "LOS" / "Trajectory_A" / "Case_1")


@pytest.fixture(scope="module")
def cablecar():
    return track_input(generate_trace(compile_scenario(load_scenario("cablecar-descending")), 0, 0))


@pytest.fixture(scope="module")
def walk():
    return track_input(generate_trace(site_scenario(noise_m=0.1), 0, 7))


TALL = [{"id": "A1", "pos_enu_m": [0, -8, 0.5]}, {"id": "A2", "pos_enu_m": [40, -8, 6]},
        {"id": "A3", "pos_enu_m": [40, 8, 0.5]}, {"id": "A4", "pos_enu_m": [0, 8, 6]}]
"""The site's anchors at two clearly different heights: no mirror fix across the anchors' plane."""


@pytest.fixture(scope="module")
def hanyang():
    if not RUN.is_dir():
        pytest.skip("needs ../shared/data/hanyang-uwb")
    from physynth.io.importers import import_hanyang

    trace, _ = import_hanyang(RUN, crop_to_uwb=True)
    return track_input(trace, time_offset_s=0.18)


def _same(a: np.ndarray, b: np.ndarray, rtol: float = 1e-9, atol: float = 1e-9) -> None:
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))  # the same first fix
    ok = ~np.isnan(a)
    np.testing.assert_allclose(a[ok], b[ok], rtol=rtol, atol=atol)


@pytest.mark.parametrize("name, use_imu", [("cablecar", True), ("walk", False), ("hanyang", False)])
def test_fast_ekf_equals_the_per_step_recursion(name, use_imu, request):
    inp = request.getfixturevalue(name)
    fast = EkfTracker(use_imu=use_imu, reinit_m=float("inf")).fit([inp])  # the recursion has no restarts
    ref = ReferenceEkfTracker(use_imu=use_imu).fit([inp])
    assert fast.range_std_m == ref.range_std_m
    _same(fast.predict(inp), ref.predict(inp))


def test_fast_ekf_equals_the_reference_through_gating_and_resets(walk):
    # a range noise far below the real one: most updates fail the gate and the filter resets
    fast = EkfTracker(range_std_m=0.002, fit_range_std=False, reinit_m=float("inf"))
    ref = ReferenceEkfTracker(range_std_m=0.002, fit_range_std=False)
    _same(fast.predict(walk), ref.predict(walk))


@pytest.mark.parametrize("name", ["cablecar", "hanyang"])
def test_ls_prefix_and_single_step_equal_the_full_solution(name, request):
    inp = request.getfixturevalue(name)
    ls = LsTracker(block_steps=32)
    full = ls.predict_rel(inp)
    k = inp.n_steps // 3
    np.testing.assert_allclose(ls.predict_rel(inp, k), full[:k], rtol=0, atol=1e-9)
    first = int(np.searchsorted(inp.t_s, inp.first_range_s))
    for j in (first, first + 1, k, inp.n_steps - 1):  # the ekf's first fix takes one step this way
        np.testing.assert_allclose(ls.solve_step(inp, j), full[j], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [7, 8])
def test_fast_ls_equals_the_reference_where_the_fix_is_well_defined(seed):
    inp = track_input(generate_trace(site_scenario(noise_m=0.1, anchors=TALL), 0, seed))
    fast, ref = LsTracker().predict(inp), ReferenceLsTracker().predict(inp)
    _same(fast, ref, rtol=0, atol=5e-3)  # the reference's own tolerance (ftol 1e-8 on a block's cost)
    ok = ~np.isnan(fast[:, 0])
    assert np.median(np.abs(fast - ref)[ok]) < 1e-5


def _costs(inp, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-step costs of the new and the reference solver on one block of 128 steps ``stride`` apart."""
    use = np.isfinite(inp.range_m) & (inp.aoi_s <= 0.5)
    r = np.where(use, inp.range_m, 0.0)
    rows = np.flatnonzero(use.sum(axis=1) >= 1)[::stride][:128]
    warm = LsTracker().predict_rel(inp)[rows[0]]
    new = multilaterate(r[rows], use[rows], inp.anchor_pos_rel_m, warm)
    old = reference_multilaterate(r[rows], use[rows], inp.anchor_pos_rel_m, warm)
    args = (r[rows], use[rows], inp.anchor_pos_rel_m, np.broadcast_to(warm, (rows.size, 3)), 0.3, 1e-2, "soft_l1")
    return cost_terms(new, *args)[0], cost_terms(old, *args)[0]


@pytest.mark.parametrize("name", ["cablecar", "hanyang"])
def test_fast_ls_cost_is_not_above_the_reference(name, request):
    inp = request.getfixturevalue(name)
    # a block as the tracker forms it (steps close together, started near them): never above
    c_new, c_old = _costs(inp, 7)
    assert np.all(c_new <= c_old + 1e-9)
    # a hard block (steps up to ~30 s from the start): the reference stops early on most steps; a
    # different basin of the ring of near-solutions is reached on a few, with a lower total cost
    c_new, c_old = _costs(inp, 40)
    assert np.mean(c_new <= c_old + 1e-9) >= 0.9
    assert np.sum(c_new < c_old - 1e-6) >= 0.5 * c_new.size
    assert c_new.sum() < c_old.sum()


def test_ekf_max_coast_holds_the_output_through_a_gap_and_changes_nothing_else():
    from dataclasses import replace

    from physynth.records import Uwb

    tr = generate_trace(site_scenario(noise_m=0.1), 0, 7)
    u = tr.uwb
    t0, t1 = u.t_s[0] + 0.3 * tr.duration_s, u.t_s[0] + 0.6 * tr.duration_s
    assert t1 - t0 > 3.0
    gap = (u.t_s > t0) & (u.t_s < t1)  # seconds without any range
    inp = track_input(replace(tr, uwb=Uwb(t_s=u.t_s, anchor=u.anchor, range_m=np.where(gap, np.nan, u.range_m))))
    free = EkfTracker(fit_range_std=False).predict_rel(inp)
    held = EkfTracker(fit_range_std=False, max_coast_s=1.0).predict_rel(inp)
    last = np.flatnonzero(inp.fresh.any(axis=1) & (inp.t_s <= t0))[-1]
    k1 = last + int(round(inp.rate_hz))  # one second after the last range before the gap
    nxt = np.flatnonzero(inp.fresh.any(axis=1) & (inp.t_s >= t1))[0]
    before = np.arange(inp.n_steps) <= k1
    after = np.arange(inp.n_steps) >= nxt
    _same(held[before | after], free[before | after], rtol=0, atol=0)  # the filter itself is unchanged
    np.testing.assert_array_equal(held[k1:nxt], np.broadcast_to(held[k1], (nxt - k1, 3)))  # then held
    assert np.linalg.norm(free[nxt - 1] - free[k1]) > 2.0  # where the free filter walks on (9.5 m)
