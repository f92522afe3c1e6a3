"""The tracking case study (paper section V, Table IV) on real runs, with classical baselines beside it.

Training runs are real traces with ground truth; the test run is a real trace that no model and no
calibration sees. Rows of the table:

- ``NOAUG``: ``aoi-fusion`` trained on the real training runs only (paper: 200 epochs, Adam 1e-3);
- ``AUG_GAN``: the same, on the real runs plus copies whose range noise is replaced by samples of a
  small GAN trained on the real training residuals (:mod:`physynth.track.gan`);
- ``SYNTH_PHY``: ``aoi-fusion`` pre-trained on PhySynth traces only (paper: 300 epochs at 1e-3) of the
  scenario calibrated on the training runs (or ``scenario``), with path and anchor layout varied around
  the calibrated site (:data:`STUDY_VARIATION`, :mod:`physynth.track.synth`), then fine-tuned on the real
  training runs at a lower learning rate (paper: 200 epochs at 5e-5), optionally keeping a fixed subset
  of synthetic windows in the fine-tuning set (``finetune_synth_ratio``). The pre-trained network is also
  scored before fine-tuning (``SYNTH_PHY (synthetic only)``): it has seen no real range at all;
- ``bilstm``: a bidirectional LSTM trained like NOAUG; ``ls`` and ``ekf``: classical trackers;
- reference rows: the dataset authors' own estimates shipped with the test run (``LS.csv``,
  ``ESKF.csv``), scored with the same error definition (:mod:`physynth.track.scoring`).

The UWB stamps of the real runs lag their truth (Hanyang ~0.18 s); the lag is estimated on the
training runs only (:func:`physynth.calibrate.uwb_fit.fit_time_offset`) and removed from every run.

The library never prints: ``progress`` receives one short line per step; errors about the inputs are
:class:`~physynth.errors.PhySynthError` s.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..data import HANYANG_TRAJECTORY_A_RUNS as HANYANG_RUNS  # the default runs: train on the first three
from ..errors import PhySynthError
from ..records import TRUTH_UNTRUSTED_KEY, Trace, untrusted_truth
from ..scenario import Scenario, scenario_to_dict
from ..track.features import EKF_PRIOR_COAST_S
from ..track.height import HeightPrior, height_from_scenario, height_from_truth
from ..track.inputs import TrackInput, track_input
from ..track.reference import reference_estimates
from ..track.scoring import error_stats
from ..transform import ISOMETRY_META_KEY, apply_isometry
from .tracking_config import (  # noqa: F401  (the study's settings, importable from here too)
    HEIGHT_SOURCES,
    METHODS,
    NETWORK_METHODS,
    REAL_TRAINED,
    STUDY_LAYOUTS,
    STUDY_VARIATION,
    StudyConfig,
    quick_config,
)

ProgressFn = Callable[[str], None]



@dataclass(frozen=True, slots=True, kw_only=True)
class StudyRun:
    """One real run: a label, its trace and the folder of the dataset authors' estimates (if any)."""

    label: str
    trace: Trace
    reference_dir: Path | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class StudyResult:
    """Rows of the table, the configuration and what the data were; ``estimates`` per method (K, 3)."""

    rows: list[dict[str, Any]]
    config: dict[str, Any]
    data: dict[str, Any]
    estimates: dict[str, np.ndarray]
    test_input: TrackInput
    test_trusted: np.ndarray | None = None
    """(K,) grid steps of the first test run whose truth its recording trusts (None: every step)."""
    estimates_per_test: dict[str, list[np.ndarray]] = field(default_factory=dict)
    """Every method's estimates on every test run (``estimates`` holds the first test run's)."""
    test_inputs: list[TrackInput] = field(default_factory=list)
    """Every test run's inputs (``test_input`` is the first)."""
    trusted_per_test: list[np.ndarray] = field(default_factory=list)
    """Every test run's trusted steps (``test_trusted`` is the first's)."""

    def to_json(self) -> dict[str, Any]:
        return {"rows": self.rows, "config": self.config, "data": self.data}


# --------------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------------


def default_data_root() -> Path:
    """The folder holding the real datasets (``hanyang-uwb/``, ...): ``PHYSYNTH_SHARED_DATA`` (the older
    name) or ``PHYSYNTH_DATA_DIR`` when set; else ``shared/data`` beside a PhySynth clone when it holds the
    Hanyang runs (the developers' copy); else the user's cache, where :func:`physynth.data.fetch` puts
    them (:func:`physynth.data.data_root`)."""
    from ..data import DATA_DIR_ENV, data_root

    env = os.environ.get("PHYSYNTH_SHARED_DATA")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    clone = here.parents[3]  # <clone>/src/physynth/studies/tracking.py, not an installed package
    if not os.environ.get(DATA_DIR_ENV) and here.parents[2].name == "src" and (clone / "pyproject.toml").is_file():
        beside = clone.parent / "shared" / "data"
        if (beside / "hanyang-uwb").is_dir():
            return beside
    return data_root()


def hanyang_default_runs(data_root: Path | None = None) -> tuple[list[StudyRun], StudyRun]:
    """The default split: Hanyang Trajectory_A LOS Case_1, LOS Case_2, NLOS Case_1 / NLOS Case_2.

    The runs are read from dataset ``hanyang-uwb`` under ``data_root`` (default: :func:`default_data_root`);
    only the files of these four runs need to be there."""
    from ..data import dataset_path, get_dataset, missing_files
    from ..errors import DatasetError
    from ..io.importers import import_hanyang

    base = Path(data_root) if data_root is not None else default_data_root()
    runs_dir = "Dynamic_measurements"
    needed = {f: h for f, h in get_dataset("hanyang-uwb").registry().items()
              if any(f.startswith(f"{runs_dir}/{rel}/") for rel in HANYANG_RUNS)}
    try:
        root = dataset_path("hanyang-uwb", base, registry=needed) / runs_dir
    except DatasetError:
        missing = missing_files("hanyang-uwb", base, registry=needed)
        what = ("dataset hanyang-uwb is not fetched" if len(missing) == len(needed)
                else f"{len(missing)} of their {len(needed)} files are missing (first: {missing[0]})")
        raise PhySynthError(f"default Hanyang runs not found under {base / 'hanyang-uwb' / runs_dir}: {what}; "
                            "fetch them with physynth.data.fetch('hanyang-uwb'), give training and test "
                            "datasets, or set PHYSYNTH_SHARED_DATA (or PHYSYNTH_DATA_DIR) to the folder that "
                            "holds hanyang-uwb") from None
    runs = []
    for rel in HANYANG_RUNS:
        trace, _ = import_hanyang(root / rel, crop_to_uwb=True)
        runs.append(StudyRun(label=rel, trace=trace, reference_dir=root / rel))
    return runs[:3], runs[3]


def runs_from_dataset(path: str | os.PathLike) -> list[StudyRun]:
    """The traces of a PhySynth dataset directory as runs; a Hanyang import points to its own folder."""
    from ..io.dataset import read_dataset

    ds = read_dataset(path)
    out = []
    for i, t in enumerate(ds.traces):
        ref = t.meta.get("path")
        ref_dir = Path(ref) if isinstance(ref, str) and Path(ref).is_dir() else None
        label = str(t.meta.get("run") or f"{Path(path).name}[{i}]")
        out.append(StudyRun(label=label, trace=t, reference_dir=ref_dir))
    return out


def check_runs(train: Sequence[StudyRun], test: Sequence[StudyRun], cfg: StudyConfig | None = None,
                scenario: Scenario | None = None) -> None:
    if not train:
        real = [m for m in (cfg.methods if cfg else METHODS) if m in REAL_TRAINED]
        if cfg is None or real or scenario is None:
            raise PhySynthError("no training run" + (f": {', '.join(real)} train on real runs" if real else "")
                                + ("" if scenario is not None else
                                   " (without training runs, give the site's scenario for SYNTH_PHY)"))
    if not test:
        raise PhySynthError("no test run")
    for r in train:
        if len(r.trace.uwb) == 0 or not bool(r.trace.uwb.valid.any()):
            raise PhySynthError(f"training run {r.label} has no UWB range")
        if not np.any(np.all(np.isfinite(r.trace.truth.pos_enu_m), axis=1)):
            raise PhySynthError(f"training run {r.label} has no ground truth")
    for r in test:
        if r.trace.truth.t_s.size < 2 or not np.any(np.all(np.isfinite(r.trace.truth.pos_enu_m), axis=1)):
            raise PhySynthError(f"test run {r.label} has no ground truth to score against")
        if len(r.trace.uwb) == 0 or not bool(r.trace.uwb.valid.any()):
            raise PhySynthError(f"test run {r.label} has no UWB range")
    _check_disjoint(train, test)


def _check_disjoint(train: Sequence[StudyRun], test: Sequence[StudyRun]) -> None:
    """Refuse a test run that is also a training run: the same samples (the calibration's test for one
    recording given twice, :func:`physynth.calibrate.inputs.fingerprint`), or the same source
    recording (``meta["path"]`` of an import) over overlapping times, which also finds a test run that
    was turned or cropped."""
    from ..calibrate.inputs import fingerprint

    def span(t: Trace) -> tuple[float, float]:  # truth time span in the recording's own time base [s]
        t0 = float(t.meta.get("time_origin_s") or 0.0)
        return t0 + float(t.truth.t_s[0]), t0 + float(t.truth.t_s[-1])

    prints = {id(r): fingerprint(r.trace) for r in (*train, *test)}
    for r in test:
        for q in train:
            source = r.trace.meta.get("path")
            same = prints[id(r)] == prints[id(q)] or (
                isinstance(source, str) and source == q.trace.meta.get("path")
                and span(r.trace)[0] <= span(q.trace)[1] and span(q.trace)[0] <= span(r.trace)[1])
            if same:
                raise PhySynthError(f"test run {r.label} holds the same recording as training run {q.label}: "
                                    "a run may not be both trained on and scored")


def _calibrate_training_runs(traces: Sequence[Trace], progress: ProgressFn) -> tuple[Scenario, dict[str, Any]]:
    """The one place the study calibrates: the library calibration on all training runs.

    The runs may place the anchors differently: each run is taken against its own layout, channels are
    pooled per anchor id and the run-to-run ranging offsets are fitted (``anchor_policy="per-run"``);
    the scenario generates with the first run's layout. The layouts of all runs still reach the
    synthetic traces through the study's ``variation`` (``training_layouts``).
    """
    from ..calibrate import calibrate

    res = calibrate(list(traces), name="tracking-study-calibrated", anchor_policy="per-run",
                    progress=lambda m, *_: progress(f"calibrating: {m}"))
    layout = res.report.get("anchor_layout", {})
    return res.scenario, {"anchor_policy": "per-run", "anchor_conflicts": layout.get("conflicts", [])}


def _trusted_ranges(trace: Trace) -> Trace:
    """The trace with the ranges stamped inside its untrusted truth spans marked undelivered (for fits on
    truth residuals; the spans are in truth time, the stamps lag it by a fraction of a second)."""
    u = trace.uwb
    out = untrusted_truth(trace.meta, u.t_s)
    if not out.any():
        return trace
    uwb = replace(u, range_m=np.where(out, np.nan, u.range_m), reason=None)
    return replace(trace, uwb=uwb)


def study_height(cfg: StudyConfig, train_traces: Sequence[Trace], scenario: Scenario | None) -> HeightPrior | None:
    """The tag height prior every tracker of the study is given (``cfg.height``); None for ``none``."""
    if cfg.height == "none":
        return None
    if cfg.height == "given":
        return HeightPrior(float(cfg.tag_height_m), float(cfg.tag_height_std_m))
    if cfg.height == "training" and train_traces:
        return height_from_truth(train_traces)
    if scenario is None:
        raise PhySynthError("the tag height comes from the scenario's path, and no scenario was given")
    return height_from_scenario(scenario)


def _time_offset(traces: Sequence[Trace], trusted_only: bool = False) -> tuple[float, dict[str, Any]]:
    from ..calibrate.uwb_fit import fit_time_offset

    fit = fit_time_offset([_trusted_ranges(t) for t in traces] if trusted_only else list(traces))
    return float(fit.params), {"offset_s": float(fit.params), "std_error_s": fit.diagnostics.get("std_error_s"),
                               "per_run_s": fit.diagnostics.get("per_run_s")}


# --------------------------------------------------------------------------------------------------
# the study
# --------------------------------------------------------------------------------------------------


def run_tracking_study(train: Sequence[StudyRun], test: StudyRun | Sequence[StudyRun], *,
                       scenario: Scenario | None = None, config: StudyConfig | None = None,
                       progress: ProgressFn | None = None) -> StudyResult:
    """Train every method on ``train``, score it on ``test`` (see the module docstring)."""
    from ..track import require_torch

    cfg = config or StudyConfig()
    say = progress or (lambda _m: None)
    tests = [test] if isinstance(test, StudyRun) else list(test)
    check_runs(train, tests, cfg, scenario)
    torch = require_torch() if NETWORK_METHODS & set(cfg.methods) else None
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    old_threads = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(cfg.threads)
    try:
        result = (_run(train, tests, scenario, cfg, say, t_start) if cfg.ensemble == 1
                  else _run_ensemble(train, tests, scenario, cfg, say, t_start))
        # this process, all threads, and the member processes of an ensemble run with jobs > 1
        result.data["cpu_time_s"] = time.process_time() - cpu_start + result.data.pop("child_cpu_time_s", 0.0)
        return result
    finally:
        if torch is not None and old_threads is not None:
            torch.set_num_threads(old_threads)


def _net(cfg: StudyConfig, arch: str = "aoi-fusion", **extra: Any) -> Any:
    from ..track.trackers.nets import NetConfig, NetTracker

    net_cfg = NetConfig.from_settings(**{"seed": cfg.seed, "epochs": cfg.epochs, "lr": cfg.lr,
                                         "random_isometry": cfg.random_isometry, "route_frame": cfg.route_frame,
                                         "ekf_prior": cfg.ekf_prior, **cfg.net, **extra})
    return NetTracker(arch, net_cfg)


def _run(train: Sequence[StudyRun], tests: list[StudyRun], scenario: Scenario | None, cfg: StudyConfig,
         say: ProgressFn, t_start: float) -> StudyResult:
    train_traces = [r.trace for r in train]
    trusted_only = cfg.train_trusted_truth
    if train:
        say("estimating the UWB time lag on the training runs")
        offset, offset_info = _time_offset(train_traces, trusted_only)
    else:  # a site without training runs: the scenario's lag
        offset = float(scenario.uwb.time_offset_s) if scenario is not None else 0.0
        offset_info = {"offset_s": offset, "source": "scenario (no training run)"}
    height = study_height(cfg, train_traces, scenario)
    train_inputs = [track_input(r.trace, time_offset_s=offset, label=r.label, trusted_truth_only=trusted_only,
                                height=height) for r in train]
    test_inputs = [track_input(r.trace, time_offset_s=offset, label=r.label, height=height) for r in tests]
    use_imu = all(i.acc_mps2 is not None for i in train_inputs + test_inputs)
    net_extra = {"use_imu": use_imu}
    estimates: dict[str, list[np.ndarray]] = {}
    timing: dict[str, float] = {}
    notes: dict[str, Any] = {}

    def predict_all(name: str, tracker: Any) -> None:
        t0 = time.perf_counter()
        estimates[name] = [tracker.predict(i) for i in test_inputs]
        timing[f"{name}.predict_s"] = time.perf_counter() - t0

    for method in cfg.methods:
        t0 = time.perf_counter()
        if method in ("ls", "ekf"):
            from ..track.trackers import make_tracker

            say(f"{method}: running on the test run")
            tr = make_tracker(method).fit(train_inputs)
            if method == "ekf":
                notes["ekf_range_std_m"] = tr.range_std_m
        elif method == "NOAUG":
            tr = _net(cfg, **net_extra).fit(train_inputs, progress=say)
        elif method == "bilstm":
            tr = _net(cfg, "bilstm", **net_extra).fit(train_inputs, progress=say)
        elif method == "AUG_GAN":
            from ..track.gan import GanConfig, ResidualGan, augment_trace

            say("AUG_GAN: training the residual GAN")
            gan = ResidualGan(GanConfig(steps=cfg.gan_steps, seed=cfg.seed)).fit(train_traces, offset, progress=say)
            aug = [track_input(augment_trace(r.trace, gan, offset, seed=cfg.seed * 7919 + 31 * c + j),
                               time_offset_s=offset, label=f"{r.label} (GAN copy {c})",
                               trusted_truth_only=trusted_only, height=height)
                   for c in range(cfg.gan_copies) for j, r in enumerate(train)]
            notes["gan_final_losses"] = {k: float(np.mean(v[-100:])) for k, v in gan.history.items()}
            tr = _net(cfg, **net_extra).fit(train_inputs + aug, progress=say)
        elif method == "SYNTH_PHY":
            tr = _synth_phy(train, train_traces, train_inputs, scenario, cfg, net_extra, say, notes,
                            lambda name, t: predict_all(name, t), height)
            if tr is None:  # no training run: scored before fine-tuning only
                timing[f"{method}.fit_s"] = time.perf_counter() - t0
                continue
        else:  # pragma: no cover - checked by StudyConfig
            raise PhySynthError(f"unknown method {method}")
        timing[f"{method}.fit_s"] = time.perf_counter() - t0
        predict_all(method, tr)
        if hasattr(tr, "history"):
            notes[f"{method}.training"] = [{k: (v if k != "loss" else [round(x, 6) for x in v])
                                             for k, v in h.items()} for h in tr.history]
    if cfg.net.get("ekf_prior", cfg.ekf_prior) != "none" and NETWORK_METHODS & set(cfg.methods):
        from ..track.trackers.ekf import EkfTracker

        # what the networks were given: the prior alone, scored like every method
        predict_all("ekf prior", EkfTracker(use_imu=use_imu, fit_range_std=False, max_coast_s=EKF_PRIOR_COAST_S))

    refs: dict[str, list[np.ndarray]] = {}
    for r, inp in zip(tests, test_inputs, strict=True):
        origin = r.trace.meta.get("time_origin_unix_s")
        for name, est in reference_estimates(r.reference_dir, origin, inp, offset).items():
            refs.setdefault(name, []).append(apply_isometry(r.trace.meta, est))  # a turned test run
    for name, ests in refs.items():
        if len(ests) == len(tests):
            estimates[name] = ests

    rows, trusted = _score(estimates, tests, test_inputs, timing)
    data = {
        "train": [_describe(r) for r in train],
        "test": [_describe(r) for r in tests],
        "warnings": late_truth_warnings(test_inputs),
        "time_offset": offset_info,
        "use_imu": use_imu,
        "height_prior": None if height is None else height.to_dict(),
        "inputs": _input_settings(cfg),
        "grid_rate_hz": test_inputs[0].rate_hz,
        "error_definition": "||p_hat(t_k) - p(t_k)|| on the 100 Hz grid steps with truth, from the first valid "
                            "range of the test run on; reference estimates interpolated onto the same steps "
                            "(UWB lag removed as for every tracker)",
        "physynth_version": __version__,
        "wall_time_s": time.perf_counter() - t_start,
        "timing_s": timing,
        "notes": notes,
    }
    if "scenario" in notes:
        data["scenario"] = notes.pop("scenario")
    return StudyResult(rows=rows, config=cfg.to_dict(), data=data,
                       estimates={k: v[0] for k, v in estimates.items()}, test_input=test_inputs[0],
                       test_trusted=trusted[0], estimates_per_test=estimates, test_inputs=test_inputs,
                       trusted_per_test=trusted)


LATE_TRUTH_S = 2.0
"""Scored truth that goes on longer than this after a test run's last UWB range is warned about."""


def late_truth_warnings(test_inputs: Sequence[TrackInput]) -> list[str]:
    """One line per test run whose scored truth goes on more than :data:`LATE_TRUTH_S` after its last
    range (an import not cropped to its UWB span): those seconds are scored, every tracker coasting."""
    out = []
    for inp in test_inputs:
        heard = np.asarray(inp.fresh, bool).reshape(inp.n_steps, -1).any(axis=1)
        if not heard.any():
            continue
        last = float(inp.t_s[heard][-1])
        late = inp.eval_mask() & (inp.t_s > last + LATE_TRUTH_S)
        if late.any():
            out.append(f"test run {inp.label}: {late.sum() / inp.rate_hz:.1f} s of its scored truth come after its "
                       f"last UWB range (t = {last:.1f} s); every row is scored there too (import it cropped to "
                       "its UWB span, e.g. --crop-to-uwb)")
    return out


def _score(estimates: dict[str, list[np.ndarray]], tests: Sequence[StudyRun], test_inputs: list[TrackInput],
           timing: dict[str, float]) -> tuple[list[dict[str, Any]], list[np.ndarray]]:
    """The rows of ``estimates`` on the test runs, and each test input's trusted steps (``rmse_trusted_m``
    only when some test run flags spans where its truth errs)."""
    trusted = [~untrusted_truth(r.trace.meta, inp.t_s) for r, inp in zip(tests, test_inputs, strict=True)]
    flagged = any(r.trace.meta.get(TRUTH_UNTRUSTED_KEY) for r in tests)
    return _rows(estimates, test_inputs, timing, trusted if flagged else None), trusted


def _run_ensemble(train: Sequence[StudyRun], tests: list[StudyRun], scenario: Scenario | None, cfg: StudyConfig,
                  say: ProgressFn, t_start: float) -> StudyResult:
    """``cfg.ensemble`` whole studies, seeds ``cfg.seed`` on; every row scores the mean of their estimates."""
    configs = [replace(cfg, seed=cfg.seed + j, ensemble=1, jobs=1) for j in range(cfg.ensemble)]
    prefixes = [f"ensemble member {j + 1}/{cfg.ensemble} (seed {c.seed}): " for j, c in enumerate(configs)]
    child_cpu_s = 0.0
    if cfg.jobs > 1:
        members, child_cpu_s = studies_at_once([(train, tests, scenario, c) for c in configs], prefixes, cfg.jobs, say)
    else:
        members = [_run(train, tests, scenario, c, lambda m, prefix=prefix: say(prefix + m), t_start)
                   for c, prefix in zip(configs, prefixes, strict=True)]
    first = members[0]
    mean = {name: [np.mean([m.estimates_per_test[name][i] for m in members], axis=0) for i in range(len(tests))]
            for name in first.estimates_per_test}
    test_inputs = first.test_inputs  # the same in every member (the lag comes from the training runs)
    timing: dict[str, float] = {}
    for m in members:
        for k, v in m.data["timing_s"].items():
            timing[k] = timing.get(k, 0.0) + v
    rows, trusted = _score(mean, tests, test_inputs, timing)
    data = {**first.data, "timing_s": timing, "wall_time_s": time.perf_counter() - t_start,
            "ensemble": {"members": cfg.ensemble, "seeds": [cfg.seed + j for j in range(cfg.ensemble)],
                         "scored": "every row: the mean of the members' estimates at each grid step",
                         "member_rows": [m.rows for m in members], "jobs": cfg.jobs},
            "child_cpu_time_s": child_cpu_s}
    return StudyResult(rows=rows, config=cfg.to_dict(), data=data, estimates={k: v[0] for k, v in mean.items()},
                       test_input=test_inputs[0], test_trusted=trusted[0], estimates_per_test=mean,
                       test_inputs=test_inputs, trusted_per_test=trusted)


def _member_main(j: int, train: Sequence[StudyRun], tests: list[StudyRun], scenario: Scenario | None,
                 cfg: StudyConfig, messages: Any) -> None:
    """One study in a process of its own: its progress, then its result and CPU time (or its error), as
    ``(kind, j, payload)`` on ``messages``."""
    try:
        from ..track import require_torch

        torch = require_torch() if NETWORK_METHODS & set(cfg.methods) else None
        if torch is not None:
            torch.set_num_threads(cfg.threads)
        cpu = time.process_time()
        result = _run(train, tests, scenario, cfg, lambda m: messages.put(("say", j, m)), time.perf_counter())
        messages.put(("done", j, (result, time.process_time() - cpu)))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the parent, which raises it
        messages.put(("error", j, exc))


StudySpec = tuple[Sequence[StudyRun], list[StudyRun], Scenario | None, StudyConfig]
"""One study to run: training runs, test runs, scenario (or None) and configuration."""


def studies_at_once(specs: Sequence[StudySpec], prefixes: list[str], jobs: int,
                    say: ProgressFn) -> tuple[list[StudyResult], float]:
    """Whole studies (the members of an ensemble, the folds and seeds of a protocol), ``jobs`` at a time,
    each in a spawned process (no state shared with this one); their progress is relayed to ``say`` with
    their prefix as it comes. A study's error is raised here; on any error or interruption the studies still
    running are terminated. Returns the results in the order of ``specs`` and their processes' CPU time."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    messages = ctx.Queue()
    configs = [spec[3] for spec in specs]
    todo, running, done = list(range(len(specs))), {}, {}
    try:
        while todo or running:
            while todo and len(running) < jobs:
                j = todo.pop(0)
                running[j] = ctx.Process(target=_member_main, name=f"physynth-study-{j + 1}",
                                         args=(j, *specs[j], messages))
                running[j].start()
            kind, j, payload = next_member_message(messages, running, configs)
            if kind == "say":
                say(prefixes[j] + payload)
            elif kind == "done":
                done[j] = payload
                running.pop(j).join()
            else:
                raise payload
    finally:
        for proc in running.values():
            proc.terminate()
        for proc in running.values():
            proc.join()
    return [done[j][0] for j in range(len(configs))], float(sum(c for _, c in done.values()))


def next_member_message(messages: Any, running: dict[int, Any],
                        configs: list[StudyConfig]) -> tuple[str, int, Any]:
    """The next ``(kind, j, payload)`` the study processes of :func:`studies_at_once` put on ``messages``
    (``running``: their processes by index; ``configs``: their configurations); a
    :class:`~physynth.errors.PhySynthError` naming the member and its exit code for one that ended without
    a word."""
    import queue

    while True:
        try:
            return messages.get(timeout=0.5)
        except queue.Empty:
            dead = [j for j, proc in running.items() if not proc.is_alive()]
        if dead:  # it may have put its result just before it ended: one more look
            try:
                return messages.get(timeout=1.0)
            except queue.Empty:
                j = dead[0]
                raise PhySynthError(f"ensemble member {j + 1} (seed {configs[j].seed}) ended without a result "
                                    f"(exit code {running[j].exitcode})") from None


def _input_settings(cfg: StudyConfig) -> dict[str, Any]:
    """How the network inputs were built (recorded in ``results.json``)."""
    from ..track import features as ti

    weighted = bool(cfg.net.get("age_weighted_direction", True))
    return {"age_weighted_direction": weighted,
            "direction_range_std_m": ti.DIRECTION_RANGE_STD_M if weighted else None,
            "direction_range_rate_mps": ti.DIRECTION_RANGE_RATE_MPS if weighted else None,
            "direction_ridge_m2": ti.DIRECTION_RIDGE_M2}


def _synth_phy(train: Sequence[StudyRun], train_traces: list[Trace], train_inputs: list[TrackInput],
               scenario: Scenario | None, cfg: StudyConfig, net_extra: dict[str, Any], say: ProgressFn,
               notes: dict[str, Any], score_pretrained: Callable[[str, Any], None],
               height: HeightPrior | None = None) -> Any:
    """Pre-train on PhySynth traces, score, fine-tune on the real runs; without training runs (a site known
    from its survey only) the pre-trained network is the result, scored as ``SYNTH_PHY (survey only)``
    (returns None)."""
    from ..track.torch_data import SyntheticWindows, TraceWindows

    if scenario is None:
        say("SYNTH_PHY: calibrating a scenario on the training runs")
        scenario, cal = _calibrate_training_runs(train_traces, say)
        notes["calibration"] = cal
    variation = cfg.variation
    if cfg.training_layouts:
        n = len(scenario.anchors)
        layouts = tuple(tuple(tuple(round(float(v), 4) for v in p) for p in t.anchors.pos_enu_m)
                        for t in train_traces if len(t.anchors) == n)
        variation = variation.model_copy(update={"layouts": [list(map(list, lay)) for lay in layouts]})
    notes["scenario"] = {"name": scenario.name, "scenario": scenario_to_dict(scenario),
                         "variation": variation.model_dump(mode="python"), "root_seed": cfg.seed}
    net = _net(cfg, **net_extra)
    synth = SyntheticWindows(scenario, cfg.n_synth_traces, cfg.seed, net.window_spec(),
                             windows_per_trace=cfg.synth_windows_per_trace, variation=variation,
                             cache_size=cfg.n_synth_traces, height=height)
    say(f"SYNTH_PHY: generating {cfg.n_synth_traces} synthetic traces")
    for i in range(cfg.n_synth_traces):
        synth.arrays(i)  # fill the cache once; every epoch then reads the same traces
    net.train(synth, epochs=cfg.pretrain_epochs, lr=cfg.pretrain_lr, stage="pre-train (synthetic)", progress=say)
    if not train:
        score_pretrained(SURVEY_ONLY, net)
        return None
    score_pretrained("SYNTH_PHY (synthetic only)", net)
    real = TraceWindows(train_inputs, net.window_spec())
    data, n_synth = finetune_windows(real, synth, cfg.finetune_synth_ratio, cfg.seed)
    notes["finetune_windows"] = {"real": len(real), "synthetic": n_synth}
    net.train(data, epochs=cfg.finetune_epochs, lr=cfg.finetune_lr,
              stage="fine-tune (real)" if n_synth == 0 else "fine-tune (real + synthetic)", progress=say)
    return net


SURVEY_ONLY = "SYNTH_PHY (survey only)"
"""The row of a study without training runs: the network pre-trained on PhySynth data of a scenario built
from the site's anchor survey and route, never fine-tuned (it has seen no real range)."""

FINETUNE_MIX_KEY = 7
"""spawn_key of the draw of the synthetic windows kept for fine-tuning (``SeedSequence(seed, (key,))``)."""


def finetune_windows(real: Any, synth: Any, ratio: float, seed: int) -> tuple[Any, int]:
    """The fine-tuning set: every real window plus ``round(ratio * len(real))`` synthetic windows.

    The synthetic windows are a fixed subset of the pre-training windows drawn without replacement from
    ``SeedSequence(seed, spawn_key=(FINETUNE_MIX_KEY,))`` (at most all of them), so the network keeps
    seeing the variety of layouts, outages and NLOS episodes of the synthetic traces while it adapts to
    the real runs (rehearsal against forgetting). Returns the dataset and the number of synthetic windows.
    """
    import torch

    n = min(int(round(ratio * len(real))), len(synth))
    if n <= 0:
        return real, 0
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(FINETUNE_MIX_KEY,)))
    idx = np.sort(rng.choice(len(synth), size=n, replace=False))
    return torch.utils.data.ConcatDataset([real, torch.utils.data.Subset(synth, idx.tolist())]), n


def _describe(r: StudyRun) -> dict[str, Any]:
    t = r.trace
    return {"label": r.label, "duration_s": round(t.duration_s, 3), "n_uwb_valid": int(t.uwb.valid.sum()),
            "anchors": {a: [round(float(v), 4) for v in p] for a, p in zip(t.anchors.ids, t.anchors.pos_enu_m,
                                                                            strict=True)},
            "has_imu": t.imu is not None, "reference_dir": str(r.reference_dir) if r.reference_dir else None,
            "isometry": t.meta.get(ISOMETRY_META_KEY)}


ROW_NAMES = {
    "NOAUG": "NOAUG (aoi-fusion, real only)",
    "AUG_GAN": "AUG_GAN (aoi-fusion, real + GAN residuals)",
    "SYNTH_PHY": "SYNTH_PHY (aoi-fusion, PhySynth pre-train + real fine-tune)",
    "SYNTH_PHY (synthetic only)": "SYNTH_PHY before fine-tuning (no real data)",
    SURVEY_ONLY: "SYNTH_PHY, no real training run (the site's survey and PhySynth only)",
    "bilstm": "bilstm (real only)",
    "ls": "ls (robust multilateration)",
    "ekf": "ekf (constant velocity)",
    "ekf prior": f"ekf prior of the networks (not fitted; holds after {EKF_PRIOR_COAST_S:g} s without a range)",
}


def _rows(estimates: dict[str, list[np.ndarray]], test_inputs: list[TrackInput],
          timing: dict[str, float], trusted: list[np.ndarray] | None = None) -> list[dict[str, Any]]:
    """One row of error statistics per method; with ``trusted`` (per test input, the grid steps whose truth
    the recording trusts) also ``rmse_trusted_m``, the RMSE over those steps only."""
    truth = np.concatenate([i.pos_enu_m for i in test_inputs])
    mask = np.concatenate([i.eval_mask() for i in test_inputs])
    ok = None if trusted is None else mask & np.concatenate(trusted)
    rows = []
    for name, ests in estimates.items():
        est = np.concatenate(ests)
        st = error_stats(est, truth, mask)
        st["rmse_trusted_m"] = None if ok is None else error_stats(est, truth, ok)["rmse_m"]
        rows.append({"method": ROW_NAMES.get(name, name), "key": name, **st, "delta_rmse_pct": None,
                     "fit_s": timing.get(f"{name}.fit_s"), "predict_s": timing.get(f"{name}.predict_s")})
    base = next((r for r in rows if r["key"] == "NOAUG"), None)
    for r in rows:
        if base is not None and r is not base and np.isfinite(base["rmse_m"]) and base["rmse_m"] > 0:
            r["delta_rmse_pct"] = 100.0 * (r["rmse_m"] - base["rmse_m"]) / base["rmse_m"]
    return rows
