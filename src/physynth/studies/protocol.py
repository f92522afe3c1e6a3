"""How the tracking study holds data out, over several seeds: the protocol of ``physynth study tracking``.

A tracker trained on PhySynth data must work on runs, and on anchor layouts, that nobody trained or
calibrated on. A check in which every test layout was also a training layout measures something else:
on the Hanyang runs, leave-one-run-out (each test layout also in training) showed PhySynth pre-training
7 % better than real data alone, while on held-out runs with re-placed anchors it was 92 % worse. So:

- ``leave-one-layout-out`` (the default wherever the runs hold two or more layouts): the runs are
  grouped by anchor layout (:func:`layout_groups`: the same anchor positions, whichever id sits where),
  and each group in turn is the test set while the others train and calibrate;
- ``leave-one-run-out``: each run in turn (its layout may be in training; for sites of one layout);
- ``split``: the training and test runs as given (``--train`` / ``--test``);
- ``survey-only``: no real training run at all, only a scenario of the site (its anchor survey, a route,
  channel statistics from another site): SYNTH_PHY pre-trained on PhySynth data, ``ls`` and ``ekf``,
  scored on the real runs.

Every fold runs once per seed (:func:`run_protocol`); the summary gives, per test run and method, the
3-D, horizontal and vertical RMSE and the P95 as mean and spread over the seeds, and compares methods
pairwise on the (seed, test run) pairs: mean difference, wins, and the Wilcoxon signed-rank and paired
t-test p-values (:func:`compare_methods`), so that no conclusion rests on one seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import PhySynthError
from ..scenario import Scenario
from ..track.scoring import error_stats
from .tracking import (
    NETWORK_METHODS,
    StudyConfig,
    StudyResult,
    StudyRun,
    check_runs,
    run_tracking_study,
    studies_at_once,
)

PROTOCOLS = ("leave-one-layout-out", "leave-one-run-out", "split", "survey-only")
"""The study's protocols (module docstring)."""
LAYOUT_TOL_M = 0.15
"""Two anchor positions further apart than this [m] make two layouts."""
RUN_STATS = ("rmse_m", "rmse_2d_m", "rmse_v_m", "p95_m")
"""The per-run statistics of the summary: 3-D, horizontal and vertical RMSE, 95th percentile [m]."""

ProgressFn = Callable[[str], None]


def same_layout(a: np.ndarray, b: np.ndarray, tol_m: float = LAYOUT_TOL_M) -> bool:
    """Whether two anchor layouts (A, 3) [m] place anchors at the same positions, in any order: as many
    anchors, and every anchor of each within ``tol_m`` of one of the other's."""
    a, b = np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3)
    if a.shape != b.shape:
        return False
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return bool(np.all(d.min(axis=1) <= tol_m) and np.all(d.min(axis=0) <= tol_m))


def layout_groups(runs: Sequence[StudyRun], tol_m: float = LAYOUT_TOL_M) -> list[list[int]]:
    """Indices of ``runs`` grouped by anchor layout (:func:`same_layout` with a group's first run), in
    the order each layout first occurs."""
    groups: list[list[int]] = []
    for i, r in enumerate(runs):  # a handful of runs
        pos = r.trace.anchors.pos_enu_m
        for g in groups:
            if same_layout(runs[g[0]].trace.anchors.pos_enu_m, pos, tol_m):
                g.append(i)
                break
        else:
            groups.append([i])
    return groups


@dataclass(frozen=True, slots=True, kw_only=True)
class Fold:
    """One train/test split of a protocol."""

    name: str
    train: list[StudyRun]
    test: list[StudyRun]


def default_protocol(runs: Sequence[StudyRun], tests_given: bool) -> str:
    """``split`` when test runs are given; else ``leave-one-layout-out`` where the runs hold two or more
    layouts and ``leave-one-run-out`` where they hold one."""
    if tests_given:
        return "split"
    return "leave-one-layout-out" if len(layout_groups(runs)) >= 2 else "leave-one-run-out"


def make_folds(protocol: str, runs: Sequence[StudyRun], tests: Sequence[StudyRun] = ()) -> list[Fold]:
    """The folds of ``protocol`` over ``runs`` (``split`` and ``survey-only`` also take ``tests``)."""
    runs, tests = list(runs), list(tests)
    if protocol not in PROTOCOLS:
        raise PhySynthError(f"protocol must be one of {', '.join(PROTOCOLS)}, got '{protocol}'")
    if protocol == "split":
        if not runs or not tests:
            raise PhySynthError("the split protocol needs training runs and test runs")
        return [Fold(name="split", train=runs, test=tests)]
    if protocol == "survey-only":
        held = tests or runs
        if not held:
            raise PhySynthError("the survey-only protocol needs the real runs to score")
        return [Fold(name="survey-only", train=[], test=held)]
    if tests:
        raise PhySynthError(f"{protocol} holds out runs of the given ones itself: give no separate test runs")
    if protocol == "leave-one-run-out":
        if len(runs) < 2:
            raise PhySynthError(f"leave-one-run-out needs two or more runs, got {len(runs)}")
        return [Fold(name=f"run {r.label}", train=runs[:i] + runs[i + 1:], test=[r]) for i, r in enumerate(runs)]
    groups = layout_groups(runs)
    if len(groups) < 2:
        raise PhySynthError(f"leave-one-layout-out needs runs of two or more anchor layouts; the {len(runs)} "
                            f"run(s) share one (use leave-one-run-out)")
    return [Fold(name=f"layout {k + 1} ({', '.join(runs[i].label for i in g)})",
                 train=[r for j, r in enumerate(runs) if j not in g], test=[runs[i] for i in g])
            for k, g in enumerate(groups)]


@dataclass(slots=True, kw_only=True)
class ProtocolResult:
    """Every fold's study per seed, and the summary over seeds."""

    protocol: str
    seeds: list[int]
    folds: list[dict[str, Any]]
    per_run: list[dict[str, Any]]
    """One record per (fold, seed, test run, method): ``RUN_STATS`` of that run."""
    summary: list[dict[str, Any]] = field(default_factory=list)
    comparisons: list[dict[str, Any]] = field(default_factory=list)
    overall: list[dict[str, Any]] = field(default_factory=list)
    wall_time_s: float = 0.0
    config: dict[str, Any] = field(default_factory=dict)
    studies: list[StudyResult] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"protocol": self.protocol, "seeds": self.seeds, "folds": self.folds, "overall": self.overall,
                "summary": self.summary, "comparisons": self.comparisons, "per_run": self.per_run,
                "config": self.config, "wall_time_s": self.wall_time_s}


def per_run_records(result: StudyResult, fold: str, seed: int) -> list[dict[str, Any]]:
    """``RUN_STATS`` of every method on every test run of one study."""
    out = []
    for inp, i in zip(result.test_inputs, range(len(result.test_inputs)), strict=True):
        mask = inp.eval_mask()
        for name, ests in result.estimates_per_test.items():
            st = error_stats(ests[i], inp.pos_enu_m, mask)
            out.append({"fold": fold, "seed": seed, "run": inp.label, "method": name,
                        **{k: st[k] for k in RUN_STATS}, "n_steps": st["n_steps"]})
    return out


def _pooled(result: StudyResult, fold: str, seed: int) -> list[dict[str, Any]]:
    return [{"fold": fold, "seed": seed, "method": r["key"], **{k: r.get(k) for k in RUN_STATS}}
            for r in result.rows]


def plan(runs: Sequence[StudyRun], tests: Sequence[StudyRun], protocol: str | None, seeds: Sequence[int],
         config: StudyConfig) -> tuple[str, list[Fold], list[int]]:
    """The protocol, its folds and the seeds each fold runs with (one seed when no method trains a
    network: the classical trackers draw no seed); errors about them before any work."""
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise PhySynthError(f"seeds must be one or more distinct integers, got {seeds}")
    if not NETWORK_METHODS & set(config.methods):
        seeds = seeds[:1]
    proto = protocol or default_protocol(runs, bool(tests))
    return proto, make_folds(proto, runs, tests), seeds


def run_protocol(runs: Sequence[StudyRun], tests: Sequence[StudyRun] = (), *, protocol: str | None = None,
                 seeds: Sequence[int] = (0, 1, 2), scenario: Scenario | None = None,
                 config: StudyConfig | None = None, jobs: int = 1,
                 progress: ProgressFn | None = None) -> ProtocolResult:
    """Every fold of ``protocol`` (default :func:`default_protocol`) once per seed of ``seeds`` (once only
    when no method trains a network, :func:`plan`); ``jobs`` studies at once, each in a process of its own
    (the results do not depend on it)."""
    cfg = config or StudyConfig()
    say = progress or (lambda _m: None)
    proto, folds, seeds = plan(runs, tests, protocol, seeds, cfg)
    if proto == "survey-only" and scenario is None:
        raise PhySynthError("the survey-only protocol needs the site's scenario (its anchors, route and channel)")
    if jobs < 1:
        raise PhySynthError(f"jobs must be at least 1, got {jobs}")
    t0 = time.perf_counter()
    specs = [(fold, seed) for fold in folds for seed in seeds]
    n = len(specs)
    prefixes = [f"[{k + 1}/{n}] {fold.name}, seed {seed}: " if n > 1 else "" for k, (fold, seed) in enumerate(specs)]
    if jobs > 1 and n > 1:
        for fold in folds:
            check_runs(fold.train, fold.test, cfg, scenario)
        studies, _ = studies_at_once([(f.train, f.test, scenario, replace(cfg, seed=s)) for f, s in specs],
                                     prefixes, jobs, say)
    else:
        studies = [run_tracking_study(f.train, f.test, scenario=scenario, config=replace(cfg, seed=s),
                                      progress=lambda m, p=p: say(p + m))
                   for (f, s), p in zip(specs, prefixes, strict=True)]
    per_run: list[dict[str, Any]] = []
    pooled: list[dict[str, Any]] = []
    for (fold, seed), res in zip(specs, studies, strict=True):
        per_run += per_run_records(res, fold.name, seed)
        pooled += _pooled(res, fold.name, seed)
    out = ProtocolResult(protocol=proto, seeds=seeds, per_run=per_run, studies=studies,
                         folds=[{"name": f.name, "train": [r.label for r in f.train], "test": [r.label for r in f.test]}
                                for f in folds], config=cfg.to_dict())
    out.summary = summarize(per_run)
    out.overall = summarize_overall(pooled)
    out.comparisons = compare_methods(per_run)
    out.wall_time_s = time.perf_counter() - t0
    return out


def _mean_std(v: Sequence[float]) -> tuple[float, float]:
    a = np.asarray([x for x in v if x is not None and np.isfinite(x)], dtype=float)
    if a.size == 0:
        return float("nan"), float("nan")
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


def summarize(per_run: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (test run, method): mean and standard deviation over the seeds of every ``RUN_STATS``."""
    keys = list(dict.fromkeys((r["run"], r["method"]) for r in per_run))
    out = []
    for run, method in keys:
        recs = [r for r in per_run if r["run"] == run and r["method"] == method]
        row = {"run": run, "method": method, "n_seeds": len(recs)}
        for k in RUN_STATS:
            row[k], row[f"{k}_std"] = _mean_std([r[k] for r in recs])
        out.append(row)
    return out


def summarize_overall(pooled: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method: the RMSE pooled over each fold's test runs, averaged over folds, then mean and
    standard deviation over the seeds."""
    out = []
    for method in dict.fromkeys(r["method"] for r in pooled):
        by_seed: dict[int, list[dict[str, Any]]] = {}
        for r in pooled:
            if r["method"] == method:
                by_seed.setdefault(r["seed"], []).append(r)
        row: dict[str, Any] = {"method": method, "n_seeds": len(by_seed)}
        for k in RUN_STATS:
            row[k], row[f"{k}_std"] = _mean_std([float(np.mean([r[k] for r in recs])) for recs in by_seed.values()])
        out.append(row)
    return out


COMPARED = (("SYNTH_PHY", "NOAUG"), ("SYNTH_PHY (synthetic only)", "NOAUG"), ("SYNTH_PHY (synthetic only)", "ekf"),
            ("SYNTH_PHY (survey only)", "ekf"), ("SYNTH_PHY", "ekf"), ("NOAUG", "ekf"), ("AUG_GAN", "NOAUG"),
            ("bilstm", "NOAUG"))
"""The pairs of methods the summary compares (those that ran)."""


def compare_methods(per_run: Sequence[dict[str, Any]], pairs: Sequence[tuple[str, str]] = COMPARED,
                    stat: str = "rmse_m") -> list[dict[str, Any]]:
    """Paired comparisons of ``stat`` over the (fold, seed, test run) pairs both methods have.

    Per pair of methods: ``mean_diff_m`` (first minus second; negative: the first is better), its
    relative size against the second's mean, the wins of the first, the Wilcoxon signed-rank p-value
    (two-sided; None below 6 pairs, where it cannot reach 5 %) and the paired t-test p-value.
    """
    from scipy.stats import ttest_rel, wilcoxon

    idx = {(r["fold"], r["seed"], r["run"], r["method"]): r[stat] for r in per_run}
    out = []
    for a, b in pairs:
        keys = sorted({k[:3] for k in idx if k[3] == a} & {k[:3] for k in idx if k[3] == b}, key=str)
        xa = np.array([idx[(*k, a)] for k in keys], dtype=float)
        xb = np.array([idx[(*k, b)] for k in keys], dtype=float)
        ok = np.isfinite(xa) & np.isfinite(xb)
        xa, xb = xa[ok], xb[ok]
        if xa.size == 0:
            continue
        d = xa - xb
        p_w = None
        if xa.size >= 6 and np.any(d != 0):
            p_w = float(wilcoxon(xa, xb).pvalue)
        p_t = float(ttest_rel(xa, xb).pvalue) if xa.size >= 2 and np.std(d) > 0 else None
        out.append({"method": a, "against": b, "stat": stat, "n_pairs": int(xa.size),
                    "mean_diff_m": float(d.mean()), "rel_diff_pct": float(100.0 * d.mean() / xb.mean()),
                    "wins": int((d < 0).sum()), "p_wilcoxon": p_w, "p_ttest": p_t})
    return out
