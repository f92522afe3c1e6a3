"""The HTML validation report in a real headless browser (Debian's chromium, driven by playwright).

Loads ``report.html`` from disk and checks: no console error and no page error, every figure decoded and
visible, every table visible with its rows. Skipped, saying why, only when playwright or a chromium
executable is missing (``.ci/run`` installs chromium with apt-get).
"""

from __future__ import annotations

import os
import shutil

import pytest
from helpers import simple_scenario_dict

from physynth.generate import generate_traces
from physynth.io import write_dataset
from physynth.scenario import scenario_from_dict
from physynth.validate.render import write_report
from physynth.workflows import validate_datasets


def _chromium() -> str | None:
    for name in (os.environ.get("PHYSYNTH_CHROMIUM", ""), "chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name) if name else None
        if path:
            return path
    return None


def _browse(html_file, n_figures: int, title: str, min_tables: int) -> list[str]:
    """Open ``html_file`` in headless chromium: every figure decoded and visible, every table visible with
    its rows, the title; returns the console and page errors."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install "
                                                                 "playwright; it is in the test extra)")
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=_chromium(), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
            page.goto(html_file.as_uri(), wait_until="load")
            images = page.locator("figure img")
            assert images.count() == n_figures
            for i in range(images.count()):
                img = images.nth(i)
                img.scroll_into_view_if_needed()
                assert img.is_visible(), f"figure {i} is not visible"
                assert img.evaluate("e => e.complete && e.naturalWidth > 0"), f"figure {i} did not decode"
                box = img.bounding_box()
                assert box is not None and box["width"] > 100 and box["height"] > 50
            tables = page.locator("table")
            assert tables.count() >= min_tables
            for i in range(tables.count()):
                t = tables.nth(i)
                t.scroll_into_view_if_needed()
                assert t.is_visible(), f"table {i} is not visible"
                assert t.locator("tbody tr").count() >= 1
            assert page.title() == title
        finally:
            browser.close()
    return errors


needs_chromium = pytest.mark.skipif(_chromium() is None, reason="no chromium executable on PATH (Debian: apt-get "
                                                                "install chromium; .ci/run does it)")


@needs_chromium
def test_html_report_loads_without_errors_and_shows_everything(tmp_path):
    pytest.importorskip("matplotlib")
    scn = scenario_from_dict(simple_scenario_dict(**{"motion.cruise_speed_mps": 10.0}))
    write_dataset(tmp_path / "real", generate_traces(scn, 2, seed=1), meta={"kind": "real", "source": "test"})
    report = validate_datasets(tmp_path / "real", scenario=scn, n=3, seed=2)
    written = write_report(report, tmp_path / "report", figures=True)
    n_figures = sum(1 for k in written if k.endswith(".png"))
    assert n_figures >= 3
    errors = _browse(tmp_path / "report" / "report.html", n_figures, "PhySynth validation report", 2)
    assert not errors, errors


@needs_chromium
def test_imu_only_html_report_shows_its_figures_and_tables(tmp_path):
    """An IMU-only recording (no anchors) validated against a scenario: the error spectra and Allan
    deviations, real against synthetic, as figures beside the tables."""
    pytest.importorskip("matplotlib")
    from physynth.validate.imu_report import write_imu_report

    d = simple_scenario_dict(**{"imu.white_noise_density_mps2_per_sqrt_hz": [0.05, 0.08, 0.12]})
    scn = scenario_from_dict({**d, "anchors": []})
    write_dataset(tmp_path / "real", generate_traces(scn, 1, seed=1), meta={"kind": "real", "source": "test"})
    report = validate_datasets(tmp_path / "real", scenario=scn, n=2, seed=2)
    written = write_imu_report(report, tmp_path / "report")
    assert sorted(p.name for p in written if p.suffix == ".png") == ["imu_error_allan.png", "imu_error_psd.png"]
    errors = _browse(tmp_path / "report" / "report.html", 2, "IMU validation", 2)
    assert not errors, errors
