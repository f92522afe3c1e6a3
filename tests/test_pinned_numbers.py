"""Pinned numbers of the default preset for a fixed seed.

A refactoring must not change what a user gets for the same seed: these values were recorded before
the package was reorganised into layers and must stay exactly the same (to floating-point noise).
The IMU values were pinned again when the IMU's white noise moved to the Box-Muller sampler (a new
stream by design, docs/data-and-metrics.md section 2); every UWB, truth and availability value kept
its pin through that change.
"""

from __future__ import annotations

import numpy as np
import pytest

from physynth.evaluate.metrics import compute_metrics
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario


@pytest.fixture(scope="module")
def traces():
    cs = compile_scenario(load_scenario("cablecar-descending"))
    return [generate_trace(cs, i, 7) for i in range(3)]


def test_default_preset_metrics_are_pinned(traces):
    m = compute_metrics(traces)
    assert m.duration_s == pytest.approx(99.81, abs=1e-9)
    assert m.uwb_ge1_frac == pytest.approx(0.21248246844319776, rel=1e-12)
    assert m.uwb_ge2_frac == pytest.approx(0.12585988111934815, rel=1e-12)
    assert m.residual_std_m == pytest.approx(7.637167052352831, rel=1e-9)
    assert m.residual_median_m == pytest.approx(1.0253397271616933, rel=1e-9)
    assert m.abs_residual_p95_m == pytest.approx(18.303366932975003, rel=1e-9)
    assert m.mean_aoi_s == pytest.approx(12.818839955394836, rel=1e-9)
    assert m.imu_std_mps2 == pytest.approx((1.6313648827452216, 0.8687506034197383, 1.080016696612331), rel=1e-9)
    assert m.n_residuals == 12068


def test_one_trace_is_pinned_sample_by_sample(traces):
    t = traces[1]
    assert t.uwb.t_s.size == 11899
    assert int(t.uwb.nlos.sum()) == 3330
    assert float(t.imu.acc_mps2[1234, 0]) == pytest.approx(-0.1520036428603011, rel=1e-9)
    assert float(np.nansum(t.uwb.range_m)) == pytest.approx(619755.3811563826, rel=1e-12)


def test_a_variation_section_without_a_layout_distribution_is_pinned():
    """A ``variation`` section's traces (layouts, shuffle, random routes, NLOS spread) as the code before
    ``layout_distribution`` drew them (recorded at commit bb26961): the new field, None, changes no draw."""
    from physynth.scenario import scenario_from_dict, scenario_to_dict

    base = load_scenario("walk-hanyang")
    d = scenario_to_dict(base)
    d["variation"] = {"layouts": [[[a.pos_enu_m[0] + de, a.pos_enu_m[1], a.pos_enu_m[2]] for a in base.anchors]
                                  for de in (0.0, 2.0)],
                      "shuffle_anchors": True, "random_route_prob": 0.5, "nlos_log_std": 0.5,
                      "path_lateral_std_m": 1.0, "path_sag_std_m": 0.1}
    cs = compile_scenario(scenario_from_dict(d, "pinned variation"))
    t1, t2 = generate_trace(cs, 1, 5), generate_trace(cs, 2, 5)
    assert t1.meta["site_variation"] == {
        "layout": 1, "yaw_rad": pytest.approx(0.05441324928078726, rel=1e-12),
        "shift_m": pytest.approx([0.6911895461547867, 0.323345957430108], rel=1e-12),
        "random_route": False, "nlos_scale": pytest.approx(0.5515197811301469, rel=1e-12)}
    assert float(t1.anchors.pos_enu_m.sum()) == pytest.approx(21.768243210381765, rel=1e-12)
    assert t1.uwb.t_s.size == 9180 and float(np.nansum(t1.uwb.range_m)) == pytest.approx(177821.7540359924, rel=1e-12)
    assert t2.meta["site_variation"]["random_route"] and t2.uwb.t_s.size == 6508
    assert float(np.nansum(t2.uwb.range_m)) == pytest.approx(188908.82952832268, rel=1e-12)
    assert float(t2.anchors.pos_enu_m.sum()) == pytest.approx(21.64610776443081, rel=1e-12)
