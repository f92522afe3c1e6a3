"""The tracking study's files: ``results.json``, ``results.md`` (Table IV layout), ``estimates.npz`` and
``paths.png`` of one study (:class:`~physynth.studies.tracking.StudyResult`)."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..track.inputs import TrackInput
from ..track.scoring import error_stats
from .tracking import NETWORK_METHODS, StudyResult


def compared_with_noaug(rows: Sequence[dict[str, Any]]) -> bool:
    """Whether the table has a Δ RMSE column: NOAUG, the row every Δ is relative to, ran."""
    return any(r["key"] == "NOAUG" for r in rows)


def _schedule(c: dict[str, Any]) -> list[str]:
    """``results.md``'s schedule line, of the training stages of the methods that ran (none: no line)."""
    real_only = [m for m in ("NOAUG", "AUG_GAN", "bilstm") if m in c["methods"]]
    parts = [f"{', '.join(real_only)} {c['epochs']} epochs at {c['lr']:g}"] if real_only else []
    if "SYNTH_PHY" in c["methods"]:
        parts.append(f"SYNTH_PHY {c['pretrain_epochs']} pre-training epochs at {c['pretrain_lr']:g} on "
                     f"{c['n_synth_traces']} synthetic traces, then {c['finetune_epochs']} fine-tuning epochs at "
                     f"{c['finetune_lr']:g}" + (f" with {c['finetune_synth_ratio']:g} synthetic windows per real "
                                                "window" if c.get("finetune_synth_ratio") else ""))
    return [f"- schedule: {'; '.join(parts)}" + (" (--quick)" if c["quick"] else "")] if parts else []


def _network_lines(d: dict[str, Any], c: dict[str, Any]) -> list[str]:
    """``results.md``'s lines on how the networks saw the runs (none when no network ran)."""
    if not NETWORK_METHODS & set(c["methods"]):
        return []
    weighted = d.get("inputs", {}).get("age_weighted_direction", True)
    return ["- inputs: far-field direction " + ("weighted by the age of each range" if weighted else "unweighted"),
            "- networks' frame: " + ("each run's route frame (--frame route)" if c.get("route_frame")
                                     else "randomly turned windows, 8 turned test copies (--frame turned)"
                                     if c.get("random_isometry") else "the recorded world (--frame compass)")]


def missing_text(row: dict[str, Any]) -> str | None:
    """``"no estimate on M of N scored steps (P %)"`` for a row with ``n_missing`` steps, else None."""
    n_miss = int(row.get("n_missing") or 0)
    if n_miss == 0:
        return None
    total = n_miss + int(row.get("n_steps") or 0)
    pct = 100.0 * n_miss / total
    return f"no estimate on {n_miss} of {total} scored steps ({'< 0.1' if pct < 0.1 else f'{pct:.1f}'} %)"


def results_markdown(result: StudyResult) -> str:
    """``results.md``: Table IV layout (plus the horizontal RMSE), then what was run: only what applies to
    the methods that ran (no Δ RMSE column without NOAUG, no training schedule without a network)."""
    d, c = result.data, result.config
    delta = compared_with_noaug(result.rows)
    lines = [
        f"# Tracking study (Table IV layout): test run {', '.join(t['label'] for t in d['test'])}",
        "",
        "| Method | RMSE (m) | RMSE 2D (m) | MAE (m) | P50 (m) | P95 (m) |" + (" Δ RMSE (%) |" if delta else ""),
        "|---|---:|---:|---:|---:|---:|" + ("---:|" if delta else ""),
    ]
    for r in result.rows:
        shown = "-" if r["delta_rmse_pct"] is None else f"{r['delta_rmse_pct']:+.1f}"
        lines.append(f"| {r['method']} | {r['rmse_m']:.3f} | {r['rmse_2d_m']:.3f} | {r['mae_m']:.3f} | "
                     f"{r['p50_m']:.3f} | {r['p95_m']:.3f} |" + (f" {shown} |" if delta else ""))
    missing = [f"{r['method']}: {missing_text(r)}" for r in result.rows if missing_text(r)]
    if missing:
        lines += ["", "Rows without an estimate on some scored steps are scored on the steps they have only: "
                  + "; ".join(missing) + "."]
    lines += [f"\nWarning: {w}" for w in d.get("warnings", [])]
    trusted = [(r["method"], r["rmse_trusted_m"]) for r in result.rows if r.get("rmse_trusted_m") is not None]
    if trusted:
        lines += ["", "RMSE over the steps where the test run's truth is trusted (its recording flags the rest): "
                  + "; ".join(f"{m} {v:.3f} m" for m, v in trusted) + "."]
    lines += [
        "",
        ("Δ RMSE is relative to NOAUG. " if delta else "") + "Errors on the 100 Hz grid against the test run's "
        "ground truth; rows starting 'ref:' are the dataset authors' own estimates, scored the same way.",
        "",
        f"- training runs: {', '.join(t['label'] for t in d['train'])}",
        f"- UWB time lag removed: {d['time_offset']['offset_s']:.3f} s (estimated on the training runs)",
        *([f"- seed ensemble: every row scores the mean of {d['ensemble']['members']} studies' estimates (seeds "
           f"{', '.join(map(str, d['ensemble']['seeds']))}; each member's own rows in results.json)"]
          if d.get("ensemble") else []),
        *_schedule(c),
        *_network_lines(d, c),
        f"- seed {c['seed']}, " + (f"{c['threads']} thread(s), " if NETWORK_METHODS & set(c["methods"]) else "")
        + f"wall time {d['wall_time_s']:.0f} s, CPU time {d.get('cpu_time_s', float('nan')):.0f} s",
    ]
    return "\n".join(lines) + "\n"


ESTIMATE_PREFIX = "estimate/"
"""Key prefix of each method's estimate in ``estimates.npz`` (``estimate/SYNTH_PHY``, ...)."""


def _per_test(result: StudyResult) -> tuple[list[TrackInput], list[np.ndarray], dict[str, list[np.ndarray]]]:
    """Every test run's inputs, trusted steps and estimates per method (a result built with the first
    test run only still works)."""
    inputs = result.test_inputs or [result.test_input]
    trusted = result.trusted_per_test or [np.ones(inputs[0].n_steps, dtype=bool) if result.test_trusted is None
                                          else result.test_trusted]
    per = result.estimates_per_test or {k: [v] for k, v in result.estimates.items()}
    return inputs, trusted, per


def estimates_npz(result: StudyResult) -> bytes:
    """``estimates.npz``: every test run's grid, one after the other (run order of the table's title).

    ``t_s`` (K,) grid times [s, each run's own truth time], ``run`` (K,) the index of each step's test
    run in ``run_labels``, ``truth_enu_m`` (K, 3) (NaN where unknown), ``scored`` (K,) the steps every
    row is scored on, ``trusted`` (K,) those whose truth the recording trusts, and ``estimate/<method>``
    (K, 3) ENU [m] per row of the table, so that a row's RMSE (pooled over the test runs, as the table
    scores it) is ``error_stats(estimate, truth_enu_m, scored)``; one run's: the same on ``run == i``."""
    import io

    inputs, trusted, per = _per_test(result)
    arrays = {"t_s": np.concatenate([i.t_s for i in inputs]),
              "run": np.concatenate([np.full(i.n_steps, j, dtype=np.int64) for j, i in enumerate(inputs)]),
              "run_labels": np.array([i.label for i in inputs], dtype=str),
              "truth_enu_m": np.concatenate([i.pos_enu_m for i in inputs]),
              "scored": np.concatenate([i.eval_mask() for i in inputs]), "trusted": np.concatenate(trusted)}
    arrays |= {ESTIMATE_PREFIX + name: np.concatenate([np.asarray(e, dtype=np.float64) for e in ests])
               for name, ests in per.items()}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def write_results(result: StudyResult, out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write ``results.json``, ``results.md``, ``estimates.npz`` (:func:`estimates_npz`) and ``paths.png``
    (when matplotlib is installed) atomically."""
    from .._json import jsonable
    from ..io.atomic import atomic_write_bytes, atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"json": out / "results.json", "md": out / "results.md"}
    atomic_write_text(files["json"], json.dumps(jsonable(result.to_json()), indent=1, allow_nan=True) + "\n")
    atomic_write_text(files["md"], results_markdown(result))
    files["estimates"] = out / "estimates.npz"
    atomic_write_bytes(files["estimates"], estimates_npz(result))
    fig = plot_paths(result, out / "paths.png")
    if fig is not None:
        files["figure"] = fig
    return files


def plot_paths(result: StudyResult, path: Path) -> Path | None:
    """Estimated against true horizontal paths: one column per test run, one row per method, each panel
    titled with the RMSE on its own run (None without matplotlib)."""
    plt = pyplot()
    if plt is None:
        return None
    inputs, _, per = _per_test(result)
    keys = ([k for k in ("NOAUG", "AUG_GAN", "SYNTH_PHY", "ekf", "ref: authors' ESKF") if k in per]
            or list(per)[:5])  # e.g. --methods ls: plot what there is
    if not keys:
        return None
    fig, axes = plt.subplots(len(keys), len(inputs), figsize=(max(9.0, 6.0 * len(inputs)), 2.4 * len(keys)),
                             sharex="col", sharey="col", squeeze=False)
    for col, inp in enumerate(inputs):
        m, truth, anchors = inp.eval_mask(), inp.pos_enu_m, inp.anchor_pos_enu_m
        for ax, k in zip(axes[:, col], keys, strict=True):
            est = per[k][col]
            ax.plot(truth[m, 0], truth[m, 1], color="0.2", lw=1.2, label="truth")
            ax.plot(est[m, 0], est[m, 1], lw=0.8, alpha=0.8, label="estimate")
            ax.scatter(anchors[:, 0], anchors[:, 1], marker="^", color="tab:red", s=25, label="anchors", zorder=3)
            rmse = error_stats(est, truth, m)["rmse_m"]
            ax.set_title(f"{inp.label}\n{k}: RMSE on this run {rmse:.2f} m", fontsize=9)
            ax.set_aspect("equal", adjustable="box")
        axes[-1][col].set_xlabel("east [m]")
    for ax in axes[:, 0]:
        ax.set_ylabel("north [m]")
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle("test run" + ("s" if len(inputs) > 1 else "") + ": " + ", ".join(i.label for i in inputs),
                 fontsize=10)
    return save_figure(fig, path, dpi=120)


def pyplot():
    """matplotlib's pyplot on the Agg backend, or None without matplotlib (the figures are optional)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def save_figure(fig, path: Path, *, dpi: int) -> Path:
    """``fig`` laid out, written to ``path`` as PNG atomically (:mod:`physynth.io.atomic`) and closed."""
    import io

    from ..io.atomic import atomic_write_bytes

    plt = pyplot()
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path
