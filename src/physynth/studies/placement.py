"""Anchor placement beyond the paper: choose K of a set of candidate positions, greedily.

Every candidate becomes an anchor of the scenario (its channel: the scenario's default channel, or the
per-anchor override of the same id; all ranged at the burst start, so that the order of the candidates
does not matter); ``2 n`` traces are generated once with all candidates (common
random numbers, as in :mod:`physynth.studies.anchors`), and each trace is reduced to its fresh mask on
the 100 Hz grid and its tag positions and 1-second freshness on a 10 Hz grid. The greedy search then
adds, K times, the candidate that improves the objective most on traces 0 .. n-1 (selection);
the curve is reported on those and on the held-out traces n .. 2n-1 (an honest estimate).

Objectives:

- ``ge1``, ``ge2``, ``ge3``: fraction of grid bins with at least 1 / 2 / 3 fresh anchors (maximised).
  ``ge1`` is a coverage function, so greedy is within a factor 1 - 1/e of the best K-subset;
- ``gdop``: mean over the path of the fresh GDOP capped at :data:`GDOP_OBJECTIVE_CAP` (a point
  without a 3-D fix counts as the cap; minimised) -- the geometric part of a tracker's error.
  Ties (fewer than three anchors: every point capped) are broken by ``ge1``;
- ``hdop``: the same with the tag height known (E, N fix: a walker, a vehicle).

A tracker-error objective (:mod:`physynth.track`, when it lands) fits the same loop: reduce a trace to
what the tracker needs, evaluate the error of a subset.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._json import jsonable
from ..bounds import check_budget
from ..errors import PhySynthError
from ..evaluate.grid import age_of_information, fresh_mask, grid_times
from ..generate import compile_scenario, generate_trace
from ..progress import ProgressCallback, no_progress
from ..scenario import AnchorSpec, Scenario, scenario_from_dict, scenario_to_dict
from .anchors import _chunks, _map, worker_pool
from .dop import DOP_RATE_HZ, FRESH_AOI_S, gdop

OBJECTIVES = ("ge1", "ge2", "ge3", "gdop", "hdop")
GDOP_OBJECTIVE_CAP = 10.0
"""Fresh GDOP values above this (and points without a fix) count as this in the ``gdop`` objective."""


def read_candidates(path: str | os.PathLike) -> list[AnchorSpec]:
    """Candidate anchors from YAML/JSON (a list of ``{id, pos_enu_m, ...}`` or ``{candidates: [...]}``) or
    CSV (columns ``id,e,n,u`` [m]). One-line :class:`PhySynthError` on bad input."""
    p = Path(path)
    if not p.is_file():
        raise PhySynthError(f"candidates file {p} does not exist or is not a file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise PhySynthError(f"candidates file {p}: cannot be read ({exc})") from None
    rows: Any
    if p.suffix.lower() == ".csv":
        try:
            reader = csv.DictReader(text.splitlines())
            if reader.fieldnames is None or not {"id", "e", "n", "u"} <= {f.strip() for f in reader.fieldnames}:
                raise PhySynthError(f"candidates file {p}: a CSV needs the columns id,e,n,u")
            rows = [{"id": r["id"].strip(), "pos_enu_m": [float(r["e"]), float(r["n"]), float(r["u"])]}
                    for r in ({k.strip(): v for k, v in row.items()} for row in reader)]
        except (ValueError, TypeError, AttributeError):
            raise PhySynthError(f"candidates file {p}: a row is not id,e,n,u with numbers") from None
    else:
        import yaml

        try:
            rows = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
        except (ValueError, yaml.YAMLError) as exc:
            raise PhySynthError(f"candidates file {p}: not valid {p.suffix.lstrip('.').upper() or 'YAML'} "
                                f"({str(exc).splitlines()[0]})") from None
        if isinstance(rows, dict) and "candidates" in rows:
            rows = rows["candidates"]
    if not isinstance(rows, list) or not rows:
        raise PhySynthError(f"candidates file {p}: expected a non-empty list of candidates")
    from pydantic import ValidationError

    out = []
    for i, r in enumerate(rows):
        try:
            out.append(AnchorSpec.model_validate(r))
        except ValidationError as exc:
            e = exc.errors()[0]
            loc = ".".join(str(x) for x in e["loc"])
            raise PhySynthError(f"candidates file {p}: candidate {i}: {loc + ': ' if loc else ''}{e['msg']}") from None
    ids = [a.id for a in out]
    dup = sorted({a for a in ids if ids.count(a) > 1})
    if dup:
        raise PhySynthError(f"candidates file {p}: duplicate id(s) {', '.join(dup)}")
    return out


def candidate_scenario(scn: Scenario, candidates: Sequence[AnchorSpec], *, same_slot: bool = False) -> Scenario:
    """The scenario with the candidates as its anchors (overrides kept for candidates of the same id).

    A ``variation`` section is dropped: the candidates' positions are what the study weighs, on the
    scenario's own path. ``same_slot`` ranges every anchor at the burst start (``uwb.slot_s`` = 0):
    with many candidates the slot offsets j * slot_s would otherwise spread a burst over several 10 ms
    bins and make the >= 2 objectives depend on the candidates' order in the file.
    """
    d = scenario_to_dict(scn)
    if same_slot:
        d["uwb"]["slot_s"] = 0.0
    ids = {a.id for a in candidates}
    d["anchors"] = [a.model_dump(mode="json") for a in candidates]
    d.pop("variation", None)
    for key in ("channel_per_anchor", "availability_per_anchor"):
        d[key] = {k: v for k, v in d[key].items() if k in ids}
    d["name"] = f"{scn.name}+candidates"
    return scenario_from_dict(d, f"{scn.name} with {len(candidates)} candidate anchors")


def _reduce_chunk(scn: Scenario, seed: int, indices: Sequence[int]) -> list[tuple[int, np.ndarray, np.ndarray,
                                                                                     np.ndarray]]:
    cs = compile_scenario(scn)
    out = []
    for i in indices:
        tr = generate_trace(cs, i, seed)
        t = grid_times(tr.t0_s, tr.duration_s, scn.grid_rate_hz)
        t10 = grid_times(tr.t0_s, tr.duration_s, DOP_RATE_HZ)
        out.append((i, fresh_mask(tr, t, scn.grid_rate_hz), tr.truth.position_at(t10),
                    age_of_information(tr, t10) <= FRESH_AOI_S))
    return out


def _objective(name: str, sel: list[int], fresh: list[np.ndarray], pos: list[np.ndarray], fresh10: list[np.ndarray],
               anchors: np.ndarray) -> dict[str, float]:
    n_bins = sum(f.shape[0] for f in fresh)
    counts = [f[:, sel].sum(axis=1) for f in fresh]
    res = {f"ge{m}": float(sum(np.count_nonzero(c >= m) for c in counts) / n_bins) for m in (1, 2, 3)}
    if name in ("gdop", "hdop"):
        g = np.concatenate([gdop(p, anchors[sel], m[:, sel], known_height=name == "hdop")
                            for p, m in zip(pos, fresh10, strict=True)])
        res[name] = float(np.mean(np.minimum(g, GDOP_OBJECTIVE_CAP)))
        res[f"fresh_{name}_median"] = float(np.median(g))
    return res


@dataclass(frozen=True, slots=True, kw_only=True)
class Placement:
    """Result of :func:`greedy_placement`: the chosen ids in order and the objective curve against K."""

    objective: str
    chosen: list[str]
    steps: list[dict[str, Any]]
    candidates: list[dict[str, Any]]
    scenario: Scenario
    inputs: dict[str, Any]
    timing_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return jsonable({"objective": self.objective, "chosen": self.chosen, "steps": self.steps,
                         "candidates": self.candidates, "inputs": self.inputs, "timing_s": self.timing_s})


def greedy_placement(scn: Scenario, candidates: Sequence[AnchorSpec], *, k: int, objective: str = "ge1",
                     n: int = 20, seed: int = 0, workers: int | None = None,
                     progress: ProgressCallback | None = None, force: bool = False) -> Placement:
    """Choose ``k`` of ``candidates`` greedily for ``objective`` (:data:`OBJECTIVES`).

    Selection on traces 0 .. n-1 of root ``seed``; every step is also scored on traces n .. 2n-1. The
    ``2 n`` traces with every candidate are checked against the size budget before any work
    (:func:`physynth.bounds.check_budget`; ``force`` goes ahead anyway).
    """
    progress = progress or no_progress
    t0 = time.perf_counter()
    if objective not in OBJECTIVES:
        raise PhySynthError(f"unknown objective '{objective}'; the objectives are {', '.join(OBJECTIVES)}")
    if not 1 <= k <= len(candidates):
        raise PhySynthError(f"the number of anchors to place must lie in 1..{len(candidates)} (the number of "
                            f"candidates), got {k}")
    if n < 1:
        raise PhySynthError(f"the number of traces must be at least 1, got {n}")
    cscn = candidate_scenario(scn, candidates, same_slot=True)
    workers = max(1, int(workers or os.cpu_count() or 1))
    check_budget(cscn, 2 * n, force=force, writes=False, processes=workers)  # all its processes together
    with worker_pool(workers) as pool:
        parts = _map([(cscn, seed, c) for c in _chunks(list(range(2 * n)), 2 * workers)], _reduce_chunk, pool,
                     progress, "placement: generating", 2 * n)
    rows = sorted((r for part in parts for r in part), key=lambda r: r[0])
    sel_rows, held_rows = rows[:n], rows[n:]
    anchors = np.array([a.pos_enu_m for a in candidates], dtype=float)
    ids = [a.id for a in candidates]

    def score(sel: list[int], which: list) -> dict[str, float]:
        return _objective(objective, sel, [r[1] for r in which], [r[2] for r in which], [r[3] for r in which],
                          anchors)

    maximise = objective not in ("gdop", "hdop")
    chosen: list[int] = []
    steps = []
    for step in range(1, k + 1):
        best, best_key, best_res = -1, None, None
        for c in range(len(ids)):
            if c in chosen:
                continue
            res = score(chosen + [c], sel_rows)
            key = (res[objective] if maximise else -res[objective], res["ge1"])
            if best_key is None or key > best_key:
                best, best_key, best_res = c, key, res
        chosen.append(best)
        held = score(chosen, held_rows)
        steps.append({"k": step, "added": ids[best], "objective": best_res[objective],  # type: ignore[index]
                      "held_out_objective": held[objective], "selection": best_res, "held_out": held})
        progress(f"placement: K={step} + {ids[best]}")
    chosen_ids = [ids[c] for c in chosen]
    final = candidate_scenario(scn, [candidates[c] for c in chosen])
    t1 = time.perf_counter()
    return Placement(objective=objective, chosen=chosen_ids, steps=steps,
                     candidates=[a.model_dump(mode="json") for a in candidates],
                     scenario=final,
                     inputs={"scenario": scn.name, "n_traces_selection": n, "n_traces_held_out": n,
                             "root_seed": int(seed), "k": k, "workers": workers,
                             "maximise": maximise},
                     timing_s={"total": t1 - t0})


def placement_table_md(p: Placement) -> str:
    sense = "maximised" if p.inputs["maximise"] else "minimised"
    lines = [f"# Anchor placement: {p.inputs['scenario']}", "",
             f"Greedy choice of {p.inputs['k']} of {len(p.candidates)} candidates, objective {p.objective} ({sense}); "
             f"selection on {p.inputs['n_traces_selection']} traces, curve also on {p.inputs['n_traces_held_out']} "
             f"held-out traces (root seed {p.inputs['root_seed']}).", "",
             "| K | added | objective (selection) | objective (held out) | >=1 | >=2 | >=3 |",
             "|---|---|---|---|---|---|---|"]
    for s in p.steps:
        h = s["held_out"]
        lines.append(f"| {s['k']} | {s['added']} | {s['objective']:.4f} | {s['held_out_objective']:.4f} | "
                     f"{h['ge1']:.3f} | {h['ge2']:.3f} | {h['ge3']:.3f} |")
    lines += ["", f"Run time {p.timing_s.get('total', math.nan):.1f} s.", ""]
    return "\n".join(lines)


def placement_figure_png(p: Placement) -> bytes:
    from ..validate.figures import figure_png, require_matplotlib

    figure_cls, canvas_cls = require_matplotlib()
    fig = figure_cls(figsize=(10, 4))
    ax1, ax2 = fig.subplots(1, 2)
    ks = [s["k"] for s in p.steps]
    ax1.plot(ks, [s["objective"] for s in p.steps], "o-", label="selection traces")
    ax1.plot(ks, [s["held_out_objective"] for s in p.steps], "s--", label="held-out traces")
    for s in p.steps:
        ax1.annotate(s["added"], (s["k"], s["objective"]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax1.set_xlabel("K (anchors placed)")
    ax1.set_ylabel(p.objective)
    ax1.set_title(f"greedy placement: {p.objective} against K")
    ax1.legend()
    cand = np.array([c["pos_enu_m"] for c in p.candidates])
    ax2.plot(cand[:, 0], cand[:, 1], "o", color="0.7", label="candidates")
    chosen = {c["id"]: c["pos_enu_m"] for c in p.candidates}
    for j, a in enumerate(p.chosen):
        ax2.plot(chosen[a][0], chosen[a][1], "r^")
        ax2.annotate(str(j + 1), (chosen[a][0], chosen[a][1]), fontsize=8, xytext=(3, 3), textcoords="offset points")
    ax2.set_xlabel("E [m]")
    ax2.set_ylabel("N [m]")
    ax2.set_title("chosen anchors (order of choice)")
    ax2.set_aspect("equal", adjustable="datalim")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return figure_png(fig, canvas_cls)


def write_placement(p: Placement, out: str | os.PathLike, *, figures: bool = True,
                    overwrite: bool = False) -> list[str]:
    """Write ``placement.json``, ``placement.md``, ``scenario.yaml`` (the chosen layout) and
    ``placement.png`` into ``out`` (atomically)."""
    from ..errors import OutputExistsError
    from ..io.atomic import atomic_write_bytes, atomic_write_text
    from ..io.scenario_file import scenario_to_yaml

    out = Path(out)
    if (out / "placement.json").exists() and not overwrite:
        raise OutputExistsError(out, "holds a placement study")
    if out.exists() and not out.is_dir():
        raise PhySynthError(f"output {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "placement.json", json.dumps(p.to_dict(), indent=1) + "\n")
    atomic_write_text(out / "placement.md", placement_table_md(p))
    atomic_write_text(out / "scenario.yaml", scenario_to_yaml(p.scenario))
    written = ["placement.json", "placement.md", "scenario.yaml"]
    if figures:
        atomic_write_bytes(out / "placement.png", placement_figure_png(p))
        written.append("placement.png")
    return written
