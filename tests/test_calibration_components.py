"""The calibration as a list of components (calibrate/component.py, calibrate/pipeline.COMPONENTS): each
comes after the components it needs, runs unless its options turn it off, and the report says per
component what it fits, what it reads and whether it was fitted."""

from __future__ import annotations

import pytest

from physynth.calibrate import calibrate
from physynth.calibrate.component import Component, check_order, run_components
from physynth.calibrate.pipeline import COMPONENTS
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario


def test_every_component_comes_after_what_it_needs():
    check_order(COMPONENTS)
    names = [c.name for c in COMPONENTS]
    assert len(set(names)) == len(names)
    with pytest.raises(ValueError, match="must come before"):
        check_order(tuple(reversed(COMPONENTS)))


class _Ctx:
    """The part of CalibrationContext run_components touches."""

    def __init__(self, link: bool):
        self.fitted, self.not_fitted, self.said, self.link = {}, {}, [], link

    def progress(self, message, *_):
        self.said.append(message)

    def skip(self, name, why):
        self.not_fitted[name] = why


def _fit_b(ctx):
    ctx.skip("b", "no data for it")
    return ctx.fitted["a"] + 1


def test_run_components_fits_in_order_and_says_what_was_not_fitted():
    comps = (Component(name="a", fits="A", data="x", fit=lambda ctx: 1, step="fitting a"),
             Component(name="b", fits="B", data="y", needs=("a",), fit=_fit_b),
             Component(name="c", fits="C", data="z", needs=("a",), fit=lambda ctx: 3,
                       off=lambda ctx: None if ctx.link else "option off"))
    ctx = _Ctx(link=False)
    section = run_components(comps, ctx)
    assert ctx.fitted == {"a": 1, "b": 2} and ctx.said == ["fitting a"]
    assert section == {"a": {"fits": "A", "data": "x", "fitted": True},
                       "b": {"fits": "B", "data": "y", "fitted": False, "why": "no data for it"},
                       "c": {"fits": "C", "data": "z", "fitted": False, "why": "option off"}}
    with pytest.raises(RuntimeError, match="needs a"):
        run_components(comps[1:], _Ctx(link=True))


@pytest.fixture(scope="module")
def calibrated():
    cs = compile_scenario(load_scenario("cablecar-descending"))
    return calibrate([generate_trace(cs, i, 5) for i in range(2)], name="c")


def test_the_report_says_per_component_whether_it_was_fitted(calibrated):
    res = calibrated
    comp = res.report["components"]
    assert list(comp) == [c.name for c in COMPONENTS]
    assert comp["link_budget"] == {"fits": comp["link_budget"]["fits"], "data": comp["link_budget"]["data"],
                                   "fitted": False, "why": "link_budget=False"}
    assert all(v["fitted"] for k, v in comp.items() if k != "link_budget")


def test_without_takes_out_the_optional_effect_and_nothing_else(calibrated):
    scn, rep = calibrated.scenario, calibrated.report
    hooks = {c.name: c.without for c in COMPONENTS if c.without is not None}
    assert set(hooks) == {"timing", "ranging", "antenna_sway", "tag_nlos", "link_budget"}
    assert hooks["timing"](scn, rep).uwb.late_burst_prob == 0.0
    assert hooks["tag_nlos"](scn, rep).uwb.tag_nlos_prob == 0.0
    ranging = hooks["ranging"](scn, rep)
    assert ranging.uwb.run_offset_std_m == ranging.uwb.time_offset_std_s == 0.0
    assert ranging.channel == scn.channel and ranging.path == scn.path
    assert hooks["link_budget"](scn, rep) == scn  # not applied: nothing to take out
    sway = hooks["antenna_sway"](scn, rep)
    assert sway.uwb.antenna_sway_std_m == 0.0
    if rep["antenna_sway"]["identifiable"]:  # the white twin: the LOS std given back the swaying part
        assert sway.channel.los_std_m > scn.channel.los_std_m
