"""The output-size estimate the budget check refuses against (``physynth.bounds.estimate_size``) follows
what the Parquet writer stores: above it (an upper bound: the longest trip of the spreads), and within
twice of it, so that a dataset the default budget can hold is not refused. The in-memory table
sizes it used before were 3.4 times the bytes written: 10,000 default traces (11 GB) were refused
against the 20 GB budget as 37 GB."""

from __future__ import annotations

import pytest

from physynth import bounds
from physynth.bounds import check_budget, estimate_size
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


@pytest.mark.parametrize("preset", ["cablecar-descending", "walk-hanyang", "handheld-broad"])
def test_the_disk_estimate_bounds_what_is_written(preset, tmp_path):
    scn = load_scenario(preset)
    n = 6
    path, _ = generate_dataset(scn, n, tmp_path / "ds", seed=3, workers=1)
    written = sum(f.stat().st_size for f in path.glob("*.parquet"))
    est = estimate_size(scn, n).output_bytes
    assert written < est < 2.0 * written, (preset, written / n, est / n)


def test_ten_thousand_default_traces_fit_the_default_budget(monkeypatch):
    monkeypatch.setattr(bounds, "OUTPUT_BUDGET_BYTES", 20e9)  # the default, whatever the environment sets
    scn = load_scenario("cablecar-descending")
    est = check_budget(scn, 10_000)  # raised BudgetError at 37 GB before
    assert 10e9 < est.output_bytes < 20e9
    with pytest.raises(bounds.BudgetError, match="on disk"):
        check_budget(scn, 100_000)


def test_work_that_writes_nothing_is_held_to_its_samples(monkeypatch):
    """Studies and validation write no trace: their budget holds the samples they generate and reduce
    (the in-memory tables, a bound on their time), not the bytes a dataset of them would take."""
    monkeypatch.setattr(bounds, "OUTPUT_BUDGET_BYTES", 20e9)
    scn = load_scenario("cablecar-descending")
    est = check_budget(scn, 10_000)  # a dataset of them fits the output budget
    assert est.sample_bytes > 2 * est.output_bytes
    with pytest.raises(bounds.BudgetError, match="samples to generate and reduce"):
        check_budget(scn, 10_000, writes=False)
