"""The tracking study's results over folds and seeds: ``results.json``, ``results.md`` and a figure.

One study (one fold, one seed) is written as before (:func:`physynth.studies.tracking_report.write_results`)
with the per-run table added; several are written as their summary (:class:`ProtocolResult`) with every
study's own files in ``studies/<fold>-seed<seed>/``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .protocol import RUN_STATS, ProtocolResult
from .tracking import ROW_NAMES
from .tracking_report import pyplot, save_figure, write_results

STAT_TITLES = {"rmse_m": "RMSE 3-D", "rmse_2d_m": "RMSE 2-D", "rmse_v_m": "RMSE vertical", "p95_m": "P95 3-D"}


def _cell(row: dict[str, Any], k: str, spread: bool) -> str:
    v, s = row.get(k), row.get(f"{k}_std")
    if v is None or not np.isfinite(v):
        return "-"
    return f"{v:.3f} ± {s:.3f}" if spread and s is not None and np.isfinite(s) else f"{v:.3f}"


def _p(v: float | None) -> str:
    return "-" if v is None else (f"{v:.3f}" if v >= 0.001 else "< 0.001")


def protocol_markdown(res: ProtocolResult) -> str:
    """The summary tables: overall, per test run, and the paired comparisons."""
    spread = len(res.seeds) > 1
    unit = " (mean ± std over seeds)" if spread else ""
    lines = [f"# Tracking study: {res.protocol}, seed{'s' if spread else ''} {', '.join(map(str, res.seeds))}", ""]
    lines += ["Folds (each trained and calibrated on its training runs only, scored on its test runs):", ""]
    lines += [f"- {f['name']}: train {', '.join(f['train']) or 'none (survey only)'}; test {', '.join(f['test'])}"
              for f in res.folds]
    lines += ["", f"## Overall: each fold's test runs pooled, folds averaged{unit}", "",
              "| method | " + " | ".join(STAT_TITLES[k] + " (m)" for k in RUN_STATS) + " |",
              "|---|" + "---:|" * len(RUN_STATS)]
    for r in res.overall:
        lines.append(f"| {r['method']} | " + " | ".join(_cell(r, k, spread) for k in RUN_STATS) + " |")
    lines += ["", f"## Per test run{unit}", "",
              "| test run | method | " + " | ".join(STAT_TITLES[k] + " (m)" for k in RUN_STATS) + " |",
              "|---|---|" + "---:|" * len(RUN_STATS)]
    for r in res.summary:
        lines.append(f"| {r['run']} | {r['method']} | " + " | ".join(_cell(r, k, spread) for k in RUN_STATS) + " |")
    if res.comparisons:
        lines += ["", "## Paired comparisons of the 3-D RMSE over (fold, seed, test run)", "",
                  "| method | against | pairs | mean difference (m) | relative | wins | Wilcoxon p | t-test p |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        for c in res.comparisons:
            lines.append(f"| {c['method']} | {c['against']} | {c['n_pairs']} | {c['mean_diff_m']:+.3f} | "
                         f"{c['rel_diff_pct']:+.1f} % | {c['wins']}/{c['n_pairs']} | {_p(c['p_wilcoxon'])} | "
                         f"{_p(c['p_ttest'])} |")
        lines += ["", "A negative difference: the method is better than the one it is compared with; wins: the "
                  "pairs where it is. The Wilcoxon test needs 6 pairs or more."]
    names = sorted({r["method"] for r in res.overall} & set(ROW_NAMES))
    if names:
        lines += ["", "Methods: " + "; ".join(f"{n}: {ROW_NAMES[n]}" for n in names) + "."]
    lines += ["", f"Wall time {res.wall_time_s:.0f} s."]
    return "\n".join(lines) + "\n"


def write_protocol_results(res: ProtocolResult, out_dir: str | os.PathLike) -> dict[str, Path]:
    """``results.json`` (:meth:`ProtocolResult.to_json`, with every study's own results under ``studies``),
    ``results.md`` (:func:`protocol_markdown`), ``rmse_by_run.png`` (matplotlib installed) and, for every
    study, its own files in ``studies/<k>-seed<seed>/``. Every file is written atomically."""
    from .._json import jsonable
    from ..io.atomic import atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"json": out / "results.json", "md": out / "results.md"}
    data = res.to_json()
    data["rows"] = [{"key": r["method"], "method": ROW_NAMES.get(r["method"], r["method"]),
                     **{k: r[k] for k in r if k != "method"}} for r in res.overall]
    data["studies"] = []
    k = 0
    for f_i, _fold in enumerate(res.folds):
        for seed in res.seeds:
            study = res.studies[k]
            sub = out / "studies" / f"{f_i + 1}-seed{seed}"
            write_results(study, sub)
            data["studies"].append({"fold": f_i + 1, "seed": seed, "dir": str(sub.relative_to(out)),
                                    **study.to_json()})
            k += 1
    atomic_write_text(files["json"], json.dumps(jsonable(data), indent=1, allow_nan=True) + "\n")
    atomic_write_text(files["md"], protocol_markdown(res))
    fig = plot_runs(res, out / "rmse_by_run.png")
    if fig is not None:
        files["figure"] = fig
    return files


def plot_runs(res: ProtocolResult, path: Path) -> Path | None:
    """3-D and vertical RMSE per test run and method, mean over seeds with the seeds' spread (None
    without matplotlib)."""
    plt = pyplot()
    if plt is None:
        return None
    runs = list(dict.fromkeys(r["run"] for r in res.summary))
    methods = [m for m in dict.fromkeys(r["method"] for r in res.summary) if not m.startswith("ref:")]
    if not runs or not methods:
        return None
    idx = {(r["run"], r["method"]): r for r in res.summary}
    fig, axes = plt.subplots(2, 1, figsize=(max(7.0, 1.6 * len(runs) + 3), 6.5), sharex=True)
    width = 0.8 / len(methods)
    x = np.arange(len(runs))
    for ax, k in zip(axes, ("rmse_m", "rmse_v_m"), strict=True):
        for j, m in enumerate(methods):
            vals = [idx.get((r, m), {}).get(k, np.nan) for r in runs]
            errs = [idx.get((r, m), {}).get(f"{k}_std", 0.0) for r in runs] if len(res.seeds) > 1 else None
            ax.bar(x + (j - (len(methods) - 1) / 2) * width, vals, width, yerr=errs, capsize=2, label=m)
        ax.set_ylabel(f"{STAT_TITLES[k]} [m]")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=min(len(methods), 4))
    axes[-1].set_xticks(x, runs, rotation=15, fontsize=8)
    fig.suptitle(f"{res.protocol}: " + (f"mean over seeds {', '.join(map(str, res.seeds))} (error bars: std)"
                                        if len(res.seeds) > 1 else f"seed {res.seeds[0]}"), fontsize=10)
    return save_figure(fig, path, dpi=110)
