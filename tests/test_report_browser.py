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


@pytest.mark.skipif(_chromium() is None,
                    reason="no chromium executable on PATH (Debian: apt-get install chromium; .ci/run does it)")
def test_html_report_loads_without_errors_and_shows_everything(tmp_path):
    pytest.importorskip("matplotlib")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install "
                                                                 "playwright; it is in the test extra)")
    exe = _chromium()
    scn = scenario_from_dict(simple_scenario_dict(**{"motion.cruise_speed_mps": 10.0}))
    write_dataset(tmp_path / "real", generate_traces(scn, 2, seed=1), meta={"kind": "real", "source": "test"})
    report = validate_datasets(tmp_path / "real", scenario=scn, n=3, seed=2)
    written = write_report(report, tmp_path / "report", figures=True)
    n_figures = sum(1 for k in written if k.endswith(".png"))
    assert n_figures >= 3
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
            page.goto((tmp_path / "report" / "report.html").as_uri(), wait_until="load")
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
            assert tables.count() >= 2
            for i in range(tables.count()):
                t = tables.nth(i)
                t.scroll_into_view_if_needed()
                assert t.is_visible(), f"table {i} is not visible"
                assert t.locator("tbody tr").count() >= 1
            assert page.title() == "PhySynth validation report"
        finally:
            browser.close()
    assert not errors, errors
