"""Validation report files: ``report.json``, ``report.md`` (the paper's Tables I-II), ``report.html``
(one self-contained page, figures embedded as base64 PNG) and the figures as PNG files.

The numbers come from a :class:`~physynth.validate.report_model.ValidationReport`, the tables from
:mod:`~physynth.validate.tables` and the figures from :mod:`~physynth.validate.figures`.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping
from pathlib import Path

from ..errors import OutputExistsError, PhySynthError
from ..io.atomic import atomic_write_bytes, atomic_write_text
from ..io.scenario_file import mapping_to_yaml
from .figures import FIGURES, REPORT_FILES, available_figures, render_figures, require_matplotlib
from .report_model import ValidationReport
from .tables import _inputs_lines, _Table, _tables, _transfer_lines, table_imu

__all__ = ["FIGURES", "REPORT_FILES", "available_figures", "render_figures", "render_html", "render_markdown",
           "require_matplotlib", "write_report"]

# ---------------------------------------------------------------- markdown and HTML
def _md_escape(s: str) -> str:
    return s.replace("|", "\\|")


def _md_table(t: _Table) -> str:
    out = [f"## {t.title}", "", "| " + " | ".join(map(_md_escape, t.headers)) + " |",
           "|" + "|".join("---" if i in t.text_columns else "---:" for i in range(len(t.headers))) + "|"]
    out += ["| " + " | ".join(map(_md_escape, row)) + " |" for row in t.rows]
    if t.note:
        out += ["", t.note]
    return "\n".join(out) + "\n"


def render_markdown(report: ValidationReport, figure_files: Mapping[str, str] | None = None) -> str:
    """``report.md``: provenance, Tables I-II, extended and per-anchor tables, figure links."""
    parts = ["# PhySynth validation report", ""]
    parts += [f"- {line}" for line in _inputs_lines(report)]
    parts.append("")
    if table_imu(report) is None:
        parts += ["Table I and the IMU statistics left out: "
                  + (report.extended.get("imu_note") or "IMU data missing on a side") + ".", ""]
    for t in _tables(report):
        parts.append(_md_table(t))
    tl = _transfer_lines(report)
    if tl:
        parts += ["## Transfer without retuning (paper section IV.C)", ""] + [f"- {x}" for x in tl] + [""]
    if figure_files:
        parts += ["## Figures", ""]
        for name, file in figure_files.items():
            parts += [f"![{name}]({file})", "", f"*{FIGURES.get(name, name)}*", ""]
    return "\n".join(parts).rstrip() + "\n"


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;
color:#222;line-height:1.4}
h1{font-size:1.6em}h2{font-size:1.2em;margin-top:1.8em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .6em;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
p.note{font-size:.85em;color:#555}figure{margin:1.2em 0}img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.85em;color:#444}ul.meta{font-size:.9em}
"""


def _html_table(t: _Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.headers)
    body = []
    for row in t.rows:
        cells = [f"<td>{html.escape(c)}</td>" if i in t.text_columns else f'<td class="num">{html.escape(c)}</td>'
                 for i, c in enumerate(row)]
        body.append("<tr>" + "".join(cells) + "</tr>")
    note = f'<p class="note">{html.escape(t.note)}</p>' if t.note else ""
    return (f"<h2>{html.escape(t.title)}</h2><table><thead><tr>{head}</tr></thead>"
            f"<tbody>{''.join(body)}</tbody></table>{note}")


def render_html(report: ValidationReport, figures: Mapping[str, bytes] | None = None) -> str:
    """``report.html``: one self-contained page; figures embedded as base64 PNG."""
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             "<title>PhySynth validation report</title>", f"<style>{_CSS}</style></head><body>",
             "<h1>PhySynth validation report</h1>", '<ul class="meta">']
    parts += [f"<li>{html.escape(line)}</li>" for line in _inputs_lines(report)]
    parts.append("</ul>")
    if table_imu(report) is None:
        parts.append(f'<p class="note">Table I and the IMU statistics left out: '
                     f'{html.escape(report.extended.get("imu_note") or "IMU data missing on a side")}.</p>')
    parts += [_html_table(t) for t in _tables(report)]
    tl = _transfer_lines(report)
    if tl:
        parts.append("<h2>Transfer without retuning (paper section IV.C)</h2><ul>"
                     + "".join(f"<li>{html.escape(x)}</li>" for x in tl) + "</ul>")
    if figures:
        parts.append("<h2>Figures</h2>")
        for name, png in figures.items():
            b64 = base64.b64encode(png).decode("ascii")
            parts.append(f'<figure id="fig-{html.escape(name)}"><img alt="{html.escape(name)}" '
                         f'src="data:image/png;base64,{b64}"><figcaption>{html.escape(FIGURES.get(name, name))}'
                         "</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"



# ---------------------------------------------------------------- writing
def write_report(report: ValidationReport, out_dir: str | Path, *, figures: bool = True,
                 overwrite: bool = False) -> dict[str, Path]:
    """Write ``report.json``, ``report.md``, ``report.html``, the figure PNGs and, when the synthetic
    side was generated from a scenario, that scenario as ``scenario.yaml``.

    Each file is written atomically. Returns name -> path of every file written.

    Raises
    ------
    PhySynthError
        When ``out_dir`` already holds a report and ``overwrite`` is False, cannot be created, or
        figures are asked for without matplotlib.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PhySynthError(f"{out} exists and is not a directory")
    if (out / "report.json").exists() and not overwrite:
        raise OutputExistsError(out, "holds a report")
    pngs = render_figures(report) if figures else {}  # before touching the folder: fails cleanly
    try:
        out.mkdir(parents=True, exist_ok=True)
        written: dict[str, Path] = {}
        for stale in FIGURES:  # a figure of an earlier report that this one does not have
            if stale not in pngs and (out / f"{stale}.png").exists():
                (out / f"{stale}.png").unlink()
        for name, data in pngs.items():
            written[f"{name}.png"] = out / f"{name}.png"
            atomic_write_bytes(out / f"{name}.png", data)
        atomic_write_text(out / "report.json", report.to_json() + "\n")
        written["report.json"] = out / "report.json"
        atomic_write_text(out / "report.md", render_markdown(report, {n: f"{n}.png" for n in pngs}))
        written["report.md"] = out / "report.md"
        atomic_write_text(out / "report.html", render_html(report, pngs))
        written["report.html"] = out / "report.html"
        config = report.inputs.get("synthetic", {}).get("scenario_config")
        if config:
            atomic_write_text(out / "scenario.yaml",
                              "# scenario the synthetic traces of this report were generated from\n"
                              + mapping_to_yaml(config))
            written["scenario.yaml"] = out / "scenario.yaml"
    except OSError as exc:
        raise PhySynthError(f"cannot write the report to {out}: {exc.strerror or exc}") from None
    return written

