"""Components selected by held-out evidence (physynth.calibrate.held_out, ``calibrate --select-components``).

The evidence leaves each input run out in turn; here three synthetic walks (walk-hanyang, which
generates late stamps, run-to-run spreads, antenna sway and tag-side NLOS; two for the command, whose
one-run folds have no run-to-run spread to take out) and one synthetic trace per validation keep it to
seconds. The command's tests are in test_component_selection_cli.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from physynth.calibrate import CalibrationError, calibrate
from physynth.calibrate.held_out import (
    DROP_RULE,
    MEASURES,
    ComponentEvidence,
    calibrate_selected,
    held_out_evidence,
    optional_components,
    take_out,
)
from physynth.generate import generate_trace
from physynth.io.scenario_file import load_scenario

GENERATED = ("timing", "ranging", "antenna_sway", "tag_nlos")  # walk-hanyang generates these effects


@pytest.fixture(scope="module")
def walks():
    scn = load_scenario("walk-hanyang")
    return [generate_trace(scn, i, 7) for i in range(3)]


@pytest.fixture(scope="module")
def evidence(walks):
    calls, folds = [], {}
    # the walks without their IMU samples: the evidence compares UWB measures only, and its calibrations'
    # UWB fit does not read them (checked: the same evidence, deviations and progress calls to the last
    # digit), while the IMU calibration was a sixth of this fixture's time
    uwb_only = [replace(t, imu=None) for t in walks]
    ev = held_out_evidence(uwb_only, n=1, seed=1, progress=lambda m, d=None, t=None: calls.append((m, d, t)),
                           on_run=lambda label, res, dev, gains: folds.setdefault(label, res))
    return ev, calls, folds


@pytest.fixture(scope="module")
def two_walks_calibrated(evidence):
    """``calibrate(walks[:2], name="held-out")`` (without the IMU samples): the fold that leaves out the third
    walk calibrates exactly that (held_out_evidence hands each fold's calibration to ``on_run``); taken from
    there, not fitted again."""
    return evidence[2]["trace 2"]


def test_evidence_gives_each_optional_component_a_gain_per_left_out_run(evidence):
    ev, calls, _ = evidence
    assert list(ev.components) == [c.name for c in optional_components()]
    assert ev.runs == ["trace 0", "trace 1", "trace 2"]
    for name in GENERATED:
        c = ev.components[name]
        assert set(c.gains) == set(ev.runs), (name, c.skipped)
        assert all(len(g) == len(MEASURES) and np.all(np.isfinite(g)) for g in c.gains.values())
        assert c.combined == pytest.approx(np.mean(list(c.gains.values())))
        assert c.decision == ("drop" if c.combined < 0 else "keep")
    # the link budget needs static sweeps: not fitted in any fold, no evidence, kept
    lb = ev.components["link_budget"]
    assert not lb.gains and set(lb.skipped) == set(ev.runs) and "link_budget=False" in lb.skipped["trace 0"]
    assert lb.decision == "no evidence" and "link_budget" not in ev.dropped
    counted = [(d, t) for m, d, t in calls if d is not None]
    assert counted[-1] == (t := counted[0][1], t) and t == 3 * (2 + len(ev.components))
    assert [d for d, _ in counted] == sorted(d for d, _ in counted)  # the count only grows


def test_the_rule_drops_a_component_whose_mean_gain_is_negative():
    assert "negative" in DROP_RULE
    worse = ComponentEvidence("x", gains={"a": [1.0, 0.0, 0.0, 0.0], "b": [-3.0, -1.0, 0.0, 0.0]})
    assert worse.combined == pytest.approx(-0.375) and worse.decision == "drop"
    better = ComponentEvidence("y", gains={"a": [-1.0, 0.0, 0.0, 0.0], "b": [2.0, 0.0, 0.0, 0.0]})
    assert better.decision == "keep" and better.mean_gain == [0.5, 0.0, 0.0, 0.0]
    assert ComponentEvidence("z", skipped={"a": "not fitted"}).decision == "no evidence"


def test_taking_a_component_out_writes_the_scenario_and_report_without_it(two_walks_calibrated):
    res = two_walks_calibrated  # calibrate(walks[:2] without IMU samples, name="held-out")
    assert res.scenario.name == "held-out"
    before = res.scenario.uwb.tag_nlos_prob
    assert before > 0
    out = take_out(res, ["tag_nlos"])
    assert out.scenario.uwb.tag_nlos_prob == 0.0 and out.scenario.name == "held-out"
    item = out.report["parameters"]["uwb.tag_nlos_prob"]
    assert item["value"] == 0.0 and item["fitted"] == pytest.approx(before) and "component selection" in item["why"]
    assert out.scenario.uwb.late_burst_prob == res.scenario.uwb.late_burst_prob  # the others untouched


def test_all_is_the_calibration_as_before(walks):
    a, b = calibrate(walks[:1], name="one"), calibrate_selected(walks[:1], select_components="all", name="one")
    da, db = a.scenario.model_dump(mode="json"), b.scenario.model_dump(mode="json")
    for d in (da, db):
        del d["provenance"]["created_utc"]
    assert da == db and "component_selection" not in b.report


@pytest.mark.parametrize(("call", "needle"), [
    (lambda w: held_out_evidence(w[:1], n=1), "traces"),
    (lambda w: held_out_evidence(w, n=0), "n:"),
    (lambda w: held_out_evidence(w, n=1, left_out=[5]), "left_out"),
    (lambda w: held_out_evidence(w, n=1, components=["imu"]), "components"),
    (lambda w: calibrate_selected(w[:1]), "select_components='evidence' needs at least 2 runs"),
    (lambda w: calibrate_selected(w, select_components="best"), "select_components"),
    (lambda w: calibrate_selected(w, evidence_traces=0), "evidence_traces"),
])
def test_parameter_errors_name_the_parameter(walks, call, needle):
    with pytest.raises(CalibrationError, match=needle):
        call(walks)


def test_leave_one_out_gives_each_item_and_the_others_in_order():
    from physynth.calibrate.held_out import leave_one_out

    assert list(leave_one_out("abc")) == [(0, "a", ["b", "c"]), (1, "b", ["a", "c"]), (2, "c", ["a", "b"])]
    assert list(leave_one_out([10, 20, 30], order=[2, 0])) == [(2, 30, [10, 20]), (0, 10, [20, 30])]
