"""The report layer on its own: tables carry the report's numbers, Markdown and HTML render every table
and figure, and the report folder is written atomically and never replaced by accident."""

from __future__ import annotations

import json
import re

import pytest
from helpers import simple_scenario

from physynth.errors import OutputExistsError
from physynth.evaluate.metrics import METRIC_KEYS
from physynth.generate import compile_scenario, generate_traces
from physynth.validate.compare import compare, read_report
from physynth.validate.figures import available_figures, render_figures
from physynth.validate.render import render_html, render_markdown, write_report
from physynth.validate.tables import band_cells, table_per_anchor, table_validation


@pytest.fixture(scope="module")
def report():
    scn = compile_scenario(simple_scenario(**{"channel.los_std_m": 0.2, "channel.nlos_prob": 0.1,
                                              "availability.dropout_prob": 0.2,
                                              "imu.white_noise_density_mps2_per_sqrt_hz": [0.1, 0.1, 0.1]}))
    return compare(list(generate_traces(scn, 2, seed=1)), generate_traces(scn, 3, seed=2),
                   inputs={"real": {"path": "in-memory"}})


def test_validation_table_shows_the_reports_numbers(report):
    rows = {row[0]: row for row in table_validation(report).rows}
    for label, key in (("UWB ≥ 1 (frac.)", "uwb_ge1_frac"), ("Mean AoI (s)", "mean_aoi_s"),
                       ("Duration (s)", "duration_s")):
        real, synth = (float(v.split()[0]) for v in rows[label][1:3])  # "0.28 (median run 0.082)"
        assert real == pytest.approx(report.real[key], abs=0.006), key
        assert synth == pytest.approx(report.synthetic[key], abs=0.006), key
    typical = float(rows["Mean AoI (s)"][2].split("median run ")[1].rstrip(")"))
    assert typical == pytest.approx(report.comparison["mean_aoi_s"]["typical"], abs=6e-4)
    assert float(rows["Fidelity score S"][2]) == pytest.approx(report.fidelity_score, abs=6e-4)
    anchors = {row[0]: row for row in table_per_anchor(report).rows}
    assert set(anchors) == set(report.per_anchor)
    for a, row in anchors.items():  # the per-anchor mean AoI: real / the median synthetic run's
        real, synth = (float(v) for v in row[3].split(" / "))
        assert real == pytest.approx(report.per_anchor[a]["real"]["mean_aoi_s"], abs=0.006), a
        assert synth == pytest.approx(report.per_anchor[a]["typical"]["mean_aoi_s"], abs=0.006), a


def test_markdown_and_html_hold_every_table_and_figure(report):
    pngs = render_figures(report)
    assert set(pngs) == set(available_figures(report.evidence)) and len(pngs) >= 5
    md = render_markdown(report, {n: f"{n}.png" for n in pngs})
    assert md.count("![") == len(pngs)
    assert sum(1 for line in md.splitlines() if re.match(r"^\|[ -:|]+\|$", line)) >= 3  # table separators
    html = render_html(report, pngs)
    assert html.count("<img ") == len(pngs) and html.count("data:image/png;base64,") == len(pngs)
    assert html.count("<table") >= 3 and "<script" not in html  # self-contained, nothing to run


def test_write_report_round_trips_and_refuses_to_replace(report, tmp_path):
    out = tmp_path / "rep"
    written = write_report(report, out, figures=False)
    assert {"report.json", "report.md", "report.html"} <= set(written)
    back = read_report(out / "report.json")
    for key in METRIC_KEYS:
        assert json.dumps(back.real[key]) == json.dumps(report.to_dict()["real"][key])
    with pytest.raises(OutputExistsError):
        write_report(report, out, figures=False)
    write_report(report, out, figures=False, overwrite=True)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary file left


def test_a_narrow_band_shows_enough_digits_to_tell_its_ends_apart():
    band, inside = band_cells({"band_5_95": [0.0771, 0.0838], "real_in_band": False}, 2)
    assert band == "0.077 – 0.084" and inside == "NO"  # at two digits both ends read 0.08
    assert band_cells({"band_5_95": [1.0, 1.0], "real_in_band": True}, 2)[0] == "1.00 – 1.00"
    assert band_cells({"band_5_95": [0.10, 0.35], "real_in_band": True}, 2)[0] == "0.10 – 0.35"


def test_the_fidelity_score_note_says_it_uses_absolute_differences(report):
    note = table_validation(report).note
    assert "absolute differences" in note and "Δavail" not in note
