"""Workflows: the orchestration that the command line and Python users share.

Each function reads its inputs (datasets, scenario files), runs the library and returns or writes the
result; none draws anything or knows the command line. Long ones take a ``progress`` callback
(:mod:`physynth.progress`). The command line (:mod:`physynth.cli`) is a thin layer over these.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._args import check_int, check_number, check_seed
from .bounds import check_budget
from .errors import AnchorMismatchError, PhySynthError
from .io import safety
from .io.dataset import iter_traces, n_traces, read_dataset, read_meta, recorded_grid_rate_hz, table_files
from .io.shards import DEFAULT_SHARD_TRACES
from .parallel import check_not_bootstrapping, require_dask, run_shards
from .progress import ProgressCallback
from .records import Trace
from .rng import new_root_seed

if TYPE_CHECKING:
    from .calibrate import CalibrationResult
    from .evaluate.metrics import Metrics
    from .generate import CompiledScenario
    from .scenario import Scenario
    from .studies.tracking_setup import TrackingStudyRun
    from .validate.compare import ValidationReport


ScenarioLike = "str | os.PathLike | Scenario | dict[str, Any]"
"""A scenario as the workflows take it: a preset name, a scenario file, a mapping or a Scenario."""


# ---------------------------------------------------------------- generate
def load_scenario(scenario: ScenarioLike) -> Scenario:
    """:func:`physynth.io.scenario_file.load_scenario`, imported on first use (the scenario model and its
    presets: an export, which needs none, starts without them)."""
    from .io.scenario_file import load_scenario as load

    return load(scenario)


def scenario_to_dict(scn: Scenario) -> dict[str, Any]:
    from .scenario import scenario_to_dict as to_dict

    return to_dict(scn)


def _scenario(scenario: ScenarioLike | CompiledScenario) -> Scenario | CompiledScenario:
    """The scenario of a preset name, file or mapping (:func:`load_scenario`); a compiled one as it is."""
    from .generate import CompiledScenario

    return scenario if isinstance(scenario, CompiledScenario) else load_scenario(scenario)


def generate_trace(scenario: ScenarioLike | CompiledScenario, index: int, root_seed: int) -> Trace:
    """:func:`physynth.generate.generate_trace` on a scenario given also as a preset name, a scenario file
    or a mapping (``physynth.generate_trace``)."""
    from . import generate

    return generate.generate_trace(_scenario(scenario), index, root_seed)


def generate_traces(scenario: ScenarioLike | CompiledScenario, n: int, seed: int | None = None,
                    start: int = 0) -> Iterator[Trace]:
    """:func:`physynth.generate.generate_traces` on a scenario given also as a preset name, a scenario file
    or a mapping (``physynth.generate_traces``); bad arguments are refused at the call."""
    from . import generate

    return generate.generate_traces(_scenario(scenario), n, seed=seed, start=start)


def generate_dataset(scn: ScenarioLike, n: int, out: str | Path, *, seed: int | None = None,
                     overwrite: bool = False, progress: ProgressCallback | None = None, workers: int = 1,
                     scheduler: str | None = None, resume: bool = False,
                     shard_traces: int = DEFAULT_SHARD_TRACES, force: bool = False,
                     inputs: Sequence[str | os.PathLike] = (), writer_process: bool = True) -> tuple[Path, int]:
    """Generate ``n`` traces and write them as a dataset directory (atomically), in shards.

    Every argument is checked before the output is touched (:class:`~physynth.errors.ArgumentError` for
    a count or seed that is not a non-negative integer); a run that fails before it wrote a shard leaves
    nothing that a later run would have to resume.

    Parameters
    ----------
    scn : Scenario, preset name, scenario file or mapping
        The scenario (:func:`physynth.io.scenario_file.load_scenario`).
    workers : int
        Worker processes (an embedded Dask cluster when > 1; :mod:`physynth.parallel`). A script that
        asks for more than one must make its calls under ``if __name__ == "__main__":`` (each worker
        process imports the script again); without it the call fails with one line saying so.
    scheduler : str, optional
        Address of an existing Dask scheduler to run the shards on instead.
    resume : bool
        Complete an unfinished (killed) run of ``out``: complete shards are kept, the others written.
        Without ``seed`` the unfinished run's root seed is used.
    shard_traces : int
        Traces per shard (:mod:`physynth.io.shards`). The output is the same for any ``workers``.
    writer_process : bool
        On one worker, write the shards in a process of its own (:mod:`physynth.io.writer_process`) when the
        machine has a core to spare; False writes them in this process (one core). The files are the same.
    force : bool
        Go ahead when the size estimate exceeds the budget (:func:`physynth.bounds.check_budget`, checked
        before any work).
    inputs : sequence of paths
        Files the run reads (e.g. the scenario file): ``out`` may not be or hold one
        (:func:`physynth.io.safety.check_output`).

    Returns the dataset path and the root seed used (drawn from OS entropy when ``seed`` is None and
    there is nothing to resume). ``progress(message, done, total)`` reports traces written.
    """
    from .generate import dataset_meta
    from .io import shards

    n = check_int(n, "n", minimum=1, what="the number of traces")
    seed = check_seed(seed)
    shard_traces = check_int(shard_traces, "shard_traces", minimum=1, what="traces per shard")
    workers = check_int(workers, "workers", minimum=1, what="the number of worker processes")
    if resume and overwrite:
        raise PhySynthError("resume and overwrite exclude each other: resume completes an unfinished run, "
                            "overwrite discards it; ask for one")
    if scheduler is None and workers > 1:
        check_not_bootstrapping()  # a worker re-running an unguarded script: fail before the output is touched
    scn = load_scenario(scn)
    local = 1 if scheduler is not None else min(workers, -(-n // shard_traces))  # processes on this machine
    check_budget(scn, n, force=force, processes=local)  # the budget holds for the workers together
    if resume:  # an output that is already complete: nothing to resume, or another run's (docs/scale.md)
        done = shards.finished_run(safety.resolve_output(out), scenario_to_dict(scn), seed, n, shard_traces)
        if done is not None:
            if progress is not None:
                progress(f"{out} is already complete: nothing to resume")
            return safety.resolve_output(out), done
    # safety hook (physynth.io.safety): what may be replaced, inputs, the output's lock, orphaned temp folders
    out, lock = safety.prepare_output(out, kind="dataset", overwrite=overwrite, inputs=inputs)
    try:
        previous = shards.read_plan(out) if resume else None
        if seed is None and previous is not None:
            seed = previous.get("root_seed")
        root = new_root_seed() if seed is None else int(seed)
        plan = shards.ShardPlan(n, shard_traces)
        if scheduler is not None or (workers > 1 and plan.n_shards > 1):
            require_dask()  # before anything is written or reported
        partial, complete = shards.prepare(out, shards.plan_record(scenario_to_dict(scn), root, n, shard_traces),
                                           resume=resume, overwrite=overwrite)
        todo = [k for k in range(plan.n_shards) if k not in complete]
        already = sum(plan.bounds(k)[1] - plan.bounds(k)[0] for k in complete)
        message = f"generating {scn.name}"
        if progress is not None:
            if complete:
                progress(f"resuming: {len(complete)} of {plan.n_shards} shard(s) already complete")
            progress(message, already, n)
        meta = dataset_meta(scn, root)
        try:
            run_shards(scn, root, partial, plan, todo, meta, workers=workers, scheduler=scheduler,
                       progress=None if progress is None else (lambda done: progress(message, already + done, n)),
                       writer_process=writer_process)
        except Exception:  # not an interruption: a killed or interrupted run stays resumable
            if not complete and not any(partial.glob("shard-*")):  # nothing generated (e.g. no scheduler,
                safety.remove_tree(partial)  # workers that did not start): nothing a later run must resume
            raise
        return shards.finalize(out, partial, plan, meta), root
    finally:
        lock.release()


# ---------------------------------------------------------------- calibrate
def export_dataset(dataset: str | os.PathLike, out: str | os.PathLike, fmt: str, *, overwrite: bool = False,
                   progress: ProgressCallback | None = None, bag_storage: str = "mcap", resume: bool = False,
                   workers: int = 1, scheduler: str | None = None) -> Path:
    """Export a dataset (:func:`physynth.io.export.export_dataset`) with its parts (one per shard of the
    dataset) on ``workers`` processes (an embedded Dask cluster when > 1) or on the Dask ``scheduler``, as
    :func:`generate_dataset` runs its shards; the output is the same for any number of workers.
    ``resume`` completes a killed export to ``out``."""
    from .io.export import export_dataset as export
    from .io.export import partial_dir
    from .parallel import run_tasks

    workers = check_int(workers, "workers", minimum=1, what="the number of worker processes")
    if scheduler is None and workers > 1:
        check_not_bootstrapping()

    def run(fn, tasks, sizes, prog):
        unfinished = (partial_dir(safety.resolve_output(out)), ".*.tmp-*")  # a bag or part being written
        return run_tasks(fn, tasks, sizes, workers=workers, scheduler=scheduler, progress=prog,
                         name="physynth-export", unfinished=unfinished)

    return export(dataset, out, fmt, overwrite=overwrite, progress=progress or (lambda *a, **k: None),
                  bag_storage=bag_storage, resume=resume, run=run)


def read_recordings(paths: str | os.PathLike | Sequence[str | os.PathLike], *,
                    allow_mixed: bool = True) -> tuple[list[Trace], list[str]]:
    """Traces of one or several dataset directories, labelled ``<dataset>/<run>`` (the name the recording's
    metadata gives it, :func:`physynth.calibrate._base.run_name`) or ``<dataset>/trace <index>``.

    ``paths`` is a sequence of directories or one directory. Unless ``allow_mixed``, datasets of
    different kinds of site are refused (:func:`physynth.calibrate.sites.check_same_site`).
    """
    from .calibrate._base import CalibrationError, run_name
    from .calibrate.sites import check_same_site, site_of

    if isinstance(paths, (str, os.PathLike)):  # one dataset, not the characters of its path
        paths = [paths]
    if not paths:
        raise CalibrationError("no dataset directories given")
    traces, sources, sites = [], [], []
    for p in paths:
        sources.append(str(Path(p)))
        these = []
        for i, t in enumerate(iter_traces(p)):  # streamed; calibration itself needs the traces together
            lab = f"{Path(p).name}/{run_name(t.meta) or f'trace {i}'}"
            these.append(Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, imu=t.imu,
                               meta={**t.meta, "label": lab}))
        sites.append(site_of(str(p), read_meta(p), these))
        check_same_site(sites, allow_mixed=allow_mixed)
        traces += these
    return traces, sources


def calibrate_datasets(paths: str | os.PathLike | Sequence[str | os.PathLike], *, allow_mixed: bool = False,
                       **kwargs: Any) -> CalibrationResult:
    """:func:`physynth.calibrate.calibrate` on every trace of one or several dataset directories, pooled
    (``paths``: a sequence of directories, or one).

    Datasets of different kinds of site are refused unless ``allow_mixed``
    (:mod:`physynth.calibrate.sites`).
    """
    from .calibrate import calibrate

    traces, sources = read_recordings(paths, allow_mixed=allow_mixed)
    return calibrate(traces, sources=sources, **kwargs)


# ---------------------------------------------------------------- inspect
def inspect_dataset(path: str | Path, *, rate_hz: float | None = None,
                    progress: ProgressCallback | None = None) -> tuple[Metrics, dict[str, Any]]:
    """Pooled section-5 metrics of a dataset, streamed trace by trace, and its ``dataset.json``.

    ``rate_hz``: the evaluation grid rate [Hz]; None takes the one the dataset records (its scenario's
    ``grid_rate_hz``, :func:`physynth.io.dataset.recorded_grid_rate_hz`; 100 Hz for imported recordings).
    Memory does not grow with the number of traces (:func:`physynth.io.dataset.iter_traces`,
    :class:`physynth.evaluate.metrics.MetricsAccumulator`). ``progress`` is called after each trace.
    """
    if rate_hz is not None:
        rate_hz = check_number(rate_hz, "rate_hz", positive=True, unit="Hz")
    meta = read_meta(path)
    rate_hz = recorded_grid_rate_hz(meta) if rate_hz is None else rate_hz
    total = n_traces(meta)
    done = 0

    def on_trace() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress("reading traces", done, total)

    try:
        from .evaluate.metrics import compute_metrics  # imported where used: not before a first trace

        return compute_metrics(iter_traces(path, meta), rate_hz, on_trace=on_trace), meta
    except ValueError as exc:  # a table that reads but does not make valid records
        raise PhySynthError(f"dataset {path}: invalid content: {exc}") from None


def _anchor_ids_of(path: str | Path) -> list[str]:
    """Anchor ids of a dataset from its (small) anchors table, in order of first appearance."""
    import pyarrow.parquet as pq

    ids: list[str] = []
    for f in table_files(Path(path), "anchors"):
        for a in pq.read_table(f, columns=["anchor_id"]).column("anchor_id").to_pylist():
            if a not in ids:
                ids.append(a)
    return ids


# ---------------------------------------------------------------- validate
def _read(reader: Callable[[str | Path], Any], path: str | Path, role: str) -> Any:
    """Read a dataset; its one-line error names the role (real or synthetic)."""
    try:
        return reader(path)
    except PhySynthError as exc:
        raise PhySynthError(f"{role} dataset: {exc}") from None
    except ValueError as exc:  # a table that reads but does not make valid records (unsorted times, ...)
        raise PhySynthError(f"{role} dataset {path}: invalid content: {exc}") from None


def _refuse_uwb_options(real: str | Path, *, anchors: Any, all_truth: bool) -> None:
    """Options about ranges given for an IMU-only real dataset: one line naming the first."""
    for given, what in ((anchors is not None, "an anchor subset"),
                        (all_truth, "comparing the ranges also where the truth errs")):
        if given:
            raise PhySynthError(f"real dataset {real} is an IMU-only recording (no UWB): {what} does not apply")


def validate_datasets(real: str | Path, *, synthetic: str | Path | None = None,
                      scenario: ScenarioLike | None = None,
                      n: int = 50, seed: int | None = None, transfer: bool = False,
                      rate_hz: float | None = None, progress: ProgressCallback | None = None,
                      anchors: Sequence[str] | None = None, force: bool = False,
                      all_truth: bool = False) -> ValidationReport:
    """Validate a real dataset against a synthetic dataset or against traces generated from a scenario.

    Parameters
    ----------
    real : path
        Dataset directory of real traces (with ground truth).
    synthetic : path, optional
        Dataset directory of synthetic traces. Exactly one of ``synthetic`` and ``scenario``.
    scenario : str, path or Scenario, optional
        Preset name, scenario file, mapping or object; ``n`` traces are generated from root seed ``seed``
        (drawn from OS entropy and recorded when None).
    transfer : bool
        Take path geometry, motion and anchor layout from the real dataset
        (:func:`physynth.calibrate.transfer_scenario`) and keep every sensor, channel and
        availability parameter of the scenario (paper section IV.C). Needs ``scenario``.
    rate_hz : float, optional
        Evaluation grid rate [Hz], the same for both sides (recorded in the report's inputs). None: the
        scenario's ``grid_rate_hz`` when a scenario is given, else the one the synthetic dataset records
        (:func:`physynth.io.dataset.recorded_grid_rate_hz`), else 100 Hz.
    progress : callable, optional
        ``progress(message, done, total)`` after each synthetic trace is generated and reduced.
    anchors : sequence of str, optional
        Relaxed subset comparison (the anchor study's): the synthetic traces keep only these anchors
        (each trace restricted to them, :func:`physynth.studies.subset.restrict_to_anchors`, so a
        scenario's traces are those of the anchor study's cell) and the real dataset is compared on
        its full set. The ids must be anchors of both sides.
    force : bool
        Generate even when the size estimate exceeds the budget (:func:`physynth.bounds.check_budget`).
    all_truth : bool
        Compare the real ranges also where the dataset says its truth errs (``truth_untrusted_s``; by
        default left out of the residual metrics, kept in availability, counted in ``inputs.real.truth``).

    Raises
    ------
    PhySynthError
        One line for every kind of bad input: both or neither of ``synthetic``/``scenario``,
        ``transfer`` without a scenario, ``n < 1``, unreadable or empty datasets, a real dataset
        without truth, anchors or valid ranges, and anchor ids that differ (without ``transfer``).
    """

    from .validate.compare import anchor_ids, check_real, compare, truth_past_uwb_s

    rate_hz = _check_validate_arguments(synthetic, scenario, transfer=transfer, n=n, rate_hz=rate_hz)
    real_ds = _read(read_dataset, real, "real")
    real_traces = real_ds.traces
    from .validate.imu_report import is_imu_only

    if is_imu_only(real_traces):  # IMU recordings without UWB: IMU error statistics only
        _refuse_uwb_options(real, anchors=anchors, all_truth=all_truth)
        return _validate_imu(real, real_ds, synthetic=synthetic, scenario=scenario, n=n, seed=seed,
                             transfer=transfer, progress=progress)
    real_traces, truth = _real_truth(real_traces, all_truth)
    check_real(real_traces, f"real dataset {real}")
    real_ids = anchor_ids(real_traces)
    inputs: dict[str, Any] = {"real": {"path": str(real), "kind": real_ds.meta.get("kind"),
                                       "source": real_ds.meta.get("source"), "anchors": real_ids, "truth": truth,
                                       "truth_past_last_uwb_s": truth_past_uwb_s(real_traces)}}
    transfer_info = None

    subset = None
    if anchors is not None:
        from .studies.subset import check_subset

        subset = check_subset(anchors, real_ids, "anchor subset (the real dataset's anchors)")
        inputs["anchor_subset"] = subset

    if synthetic is not None:
        synth_iter, total, inputs["synthetic"], recorded_rate = _synthetic_from_dataset(synthetic, real_ids, subset)
    else:
        synth_iter, total, inputs["synthetic"], transfer_info = _synthetic_from_scenario(
            scenario, real, real_traces, real_ids, subset, n=n, seed=seed, transfer=transfer, force=force)
        recorded_rate = float(inputs["synthetic"]["scenario_config"]["grid_rate_hz"])
    rate_hz = recorded_rate if rate_hz is None else rate_hz

    verb = "generating + reducing" if synthetic is None else "reducing"
    done = 0

    def on_trace() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(f"{verb} synthetic traces", done, total)

    if progress is not None:
        progress(f"{verb} synthetic traces", 0, total)
    try:
        report = compare(real_traces, synth_iter, rate_hz=rate_hz, inputs=inputs, transfer=transfer_info,
                         on_trace=on_trace)
    except ValueError as exc:  # a streamed table that reads but does not make valid records
        raise PhySynthError(f"synthetic dataset {synthetic}: invalid content: {exc}") from None
    if synthetic is not None and not report.inputs["n_residuals"]["synthetic"]:
        raise PhySynthError(f"synthetic dataset {synthetic} has no valid UWB range: nothing to compare")
    return report


def _check_validate_arguments(synthetic: str | Path | None, scenario: ScenarioLike | None, *, transfer: bool, n: int,
                              rate_hz: float | None) -> float | None:
    """:func:`validate_datasets`' choice of inputs, checked before anything is read; returns ``rate_hz``
    checked (None: the scenario's or the synthetic dataset's)."""
    if (synthetic is None) == (scenario is None):
        raise PhySynthError("give exactly one of a synthetic dataset and a scenario "
                            f"({'both' if synthetic is not None else 'neither'} given)")
    if transfer and scenario is None:
        raise PhySynthError("transfer needs a scenario (it builds a scenario for the real run's geometry)")
    if scenario is not None and n < 1:
        raise PhySynthError(f"the number of synthetic traces must be at least 1, got {n}")
    return None if rate_hz is None else check_number(rate_hz, "rate_hz", positive=True, unit="Hz")


def _real_truth(traces: Sequence[Trace], all_truth: bool) -> tuple[Sequence[Trace], dict[str, Any]]:
    """The real traces as compared (without their untrusted-truth spans when ``all_truth``) and how many
    of their valid ranges fall where the truth is untrusted."""
    import dataclasses

    from .records import TRUTH_UNTRUSTED_KEY, untrusted_truth

    n = sum(int(untrusted_truth(t.meta, t.uwb.t_s[t.uwb.valid]).sum()) for t in traces)
    total = sum(int(t.uwb.valid.sum()) for t in traces)
    info = {"untrusted_truth_ranges": n, "valid_ranges": total,
            "untrusted_left_out_of_residuals": bool(n and not all_truth)}
    if all_truth:
        traces = [dataclasses.replace(t, meta={k: v for k, v in t.meta.items() if k != TRUTH_UNTRUSTED_KEY})
                  for t in traces]
    return traces, info


def _synthetic_from_dataset(synthetic: str | Path, real_ids: Sequence[str], subset: list[str] | None
                            ) -> tuple[Iterable[Trace], int | None, dict[str, Any], float]:
    """The synthetic side read from a dataset: (streamed traces, count, provenance, the grid rate it
    records); anchors checked."""
    from .studies.subset import check_subset, restrict_to_anchors
    from .validate.compare import describe_anchor_mismatch

    synth_meta = _read(read_meta, synthetic, "synthetic")
    if synth_meta.get("n_traces") == 0:
        raise PhySynthError(f"synthetic dataset: dataset {synthetic} holds no traces")
    synth_ids = _read(_anchor_ids_of, synthetic, "synthetic")
    if subset is not None:
        check_subset(subset, synth_ids, f"anchor subset (the synthetic dataset {synthetic})")
    else:
        problem = describe_anchor_mismatch(real_ids, synth_ids, f"the synthetic dataset {synthetic}")
        if problem:
            raise AnchorMismatchError(problem)
    total = n_traces(synth_meta)
    provenance = {"path": str(synthetic), "kind": synth_meta.get("kind"),
                  "scenario_name": synth_meta.get("scenario_name"), "root_seed": synth_meta.get("root_seed"),
                  "n_traces": total}
    traces: Iterable[Trace] = _checked_stream(synthetic, synth_meta)
    if subset is not None:
        traces = (restrict_to_anchors(t, subset) for t in traces if set(subset) <= set(t.anchors.ids))
    return traces, total, provenance, recorded_grid_rate_hz(synth_meta)


def _synthetic_from_scenario(scenario: str | Path | Scenario, real: str | Path, real_traces: Sequence[Trace],
                             real_ids: Sequence[str], subset: list[str] | None, *, n: int, seed: int | None,
                             transfer: bool, force: bool
                             ) -> tuple[Iterable[Trace], int, dict[str, Any], dict[str, Any] | None]:
    """The synthetic side generated from a scenario (transferred onto the real run when asked):
    (lazy traces, count, provenance, transfer record)."""
    from .studies.subset import check_subset, restrict_to_anchors
    from .validate.compare import check_validate_budget, describe_anchor_mismatch, transfer_record

    scn = load_scenario(scenario)
    source = str(scenario) if isinstance(scenario, (str, os.PathLike)) else scn.name
    transfer_info = None
    if transfer:
        try:
            from .calibrate import transfer_scenario
        except ImportError as exc:
            raise PhySynthError(f"transfer is not available in this install ({exc})") from None
        from .calibrate._base import AnchorLayoutError

        original = scn
        try:
            scn = transfer_scenario(original, real_traces)
        except AnchorLayoutError as exc:  # several runs, several layouts: a transfer takes one
            raise AnchorLayoutError(exc.conflict, "a transferred scenario has one anchor layout: validate one "
                                                  "run at a time (a real dataset per run)") from None
        transfer_info = transfer_record(original, scn, str(real), real_ids)
    elif subset is not None:
        check_subset(subset, list(scn.anchor_ids), f"anchor subset (scenario '{scn.name}')")
    else:
        problem = describe_anchor_mismatch(real_ids, list(scn.anchor_ids), f"scenario '{scn.name}'")
        if problem:
            raise AnchorMismatchError(
                problem + "; transfer the scenario to take the anchor layout from the real dataset")
    check_validate_budget(scn, n, force=force)  # streamed, nothing written: memory of one trace, time of n
    root = new_root_seed() if seed is None else int(seed)
    provenance = {"scenario": source, "scenario_name": scn.name, "n_traces": int(n), "root_seed": root,
                  "transfer": bool(transfer), "scenario_config": scenario_to_dict(scn)}
    from .generate import compile_scenario, generate_traces

    traces: Iterable[Trace] = generate_traces(compile_scenario(scn), n, seed=root)
    if subset is not None:
        traces = (restrict_to_anchors(t, subset) for t in traces)
    return traces, n, provenance, transfer_info


def _checked_stream(path: str | Path, meta: dict[str, Any]) -> Iterable[Trace]:
    """The traces of a synthetic dataset, streamed; read errors name the role."""
    stream = iter_traces(path, meta)
    while True:
        try:
            trace = next(stream)
        except StopIteration:
            return
        except PhySynthError as exc:
            raise PhySynthError(f"synthetic dataset: {exc}") from None
        yield trace


def _validate_imu(real: str | Path, real_ds: Any, *, synthetic: str | Path | None,
                  scenario: str | Path | Scenario | None, n: int, seed: int | None, transfer: bool,
                  progress: ProgressCallback | None) -> Any:
    """:func:`validate_datasets` for IMU-only real data (:mod:`physynth.validate.imu_report`)."""
    from .validate.imu_report import validate_imu

    inputs: dict[str, Any] = {"real": {"path": str(real), "kind": real_ds.meta.get("kind"),
                                       "source": real_ds.meta.get("source"),
                                       "imu_frames": real_ds.meta.get("imu_frames")}}
    if synthetic is not None:
        synth_ds = _read(read_dataset, synthetic, "synthetic")
        inputs["synthetic"] = {"path": str(synthetic), "n_traces": len(synth_ds)}
        return validate_imu(real_ds.traces, synthetic=synth_ds.traces, inputs=inputs)
    scn = load_scenario(scenario)
    inputs["synthetic"] = {"scenario": str(scenario) if isinstance(scenario, (str, os.PathLike)) else scn.name}
    return validate_imu(real_ds.traces, scenario=scn, n=n, seed=seed, transfer=transfer, inputs=inputs,
                        progress=progress)


# ---------------------------------------------------------------- studies
def anchor_study(scenario: str | Path | Scenario, *, real: str | Path | None = None, n: int = 50,
                 seed: int | None = None, counts: Sequence[int] | None = None,
                 regimes: Sequence[str] = ("dense", "sparse", "degraded"), order: Sequence[str] | None = None,
                 workers: int | None = None, tracker_traces: int | None = None,
                 progress: ProgressCallback | None = None, force: bool = False) -> Any:
    """:func:`physynth.studies.anchors.run_anchor_study` on a scenario (preset, file or object) and,
    optionally, a real dataset directory (its traces need truth and valid ranges).

    ``seed=None`` draws a root seed from OS entropy; it is recorded in the result. ``tracker_traces``:
    traces per cell the trackers run on (default :data:`physynth.studies.anchors.TRACKER_TRACES`; 0: no
    tracker column). ``force``: go ahead even when the study's traces exceed the size budget
    (:func:`physynth.bounds.check_budget`, checked before any work).
    """
    from .studies.anchors import TRACKER_TRACES, GdopColumn, TrackerColumn, run_anchor_study
    from .validate.compare import check_real

    scn = _scenario(scenario)
    real_traces = None
    if real is not None:
        real_traces = _read(read_dataset, real, "real").traces
        check_real(real_traces, f"real dataset {real}")
    root = new_root_seed() if seed is None else int(seed)
    tracker_traces = TRACKER_TRACES if tracker_traces is None else int(tracker_traces)
    columns = (GdopColumn(),) if tracker_traces == 0 else (GdopColumn(), TrackerColumn(tracker_traces))
    study = run_anchor_study(scn, real=real_traces, n=n, seed=root, counts=counts, regimes=regimes, order=order,
                             workers=workers, columns=columns, progress=progress, force=force)
    if real is not None:
        study.reference["path"] = str(real)
    return study


def placement_study(scenario: str | Path | Scenario, candidates: str | Path, *, k: int, objective: str = "ge1",
                    n: int = 20, seed: int | None = None, regime: str = "nominal", workers: int | None = None,
                    progress: ProgressCallback | None = None, force: bool = False) -> Any:
    """:func:`physynth.studies.placement.greedy_placement` with candidates read from a file (``force``: go
    ahead even when its traces exceed the size budget)."""
    from .studies.placement import greedy_placement, read_candidates
    from .studies.regimes import apply_regime

    scn = apply_regime(_scenario(scenario), regime)
    cands = read_candidates(candidates)
    root = new_root_seed() if seed is None else int(seed)
    return greedy_placement(scn, cands, k=k, objective=objective, n=n, seed=root, workers=workers,
                            progress=progress, force=force)


_PARAMETER_SETTINGS = frozenset({"seed", "methods", "ensemble", "jobs", "quick", "random_isometry", "route_frame",
                                 "height", "tag_height_m", "tag_height_std_m"})
"""Study settings that :func:`tracking_study` takes as parameters of their own (``frame``, the height's)."""


def tracking_study(out: str | os.PathLike, *, train: Sequence[str | os.PathLike] | None = None,
                   test: Sequence[str | os.PathLike] | None = None, scenario: ScenarioLike | None = None,
                   methods: Sequence[str] | None = None, seed: int = 0, seeds: int = 3, protocol: str | None = None,
                   quick: bool = False, config: str | os.PathLike | None = None,
                   settings: Mapping[str, Any] | None = None, frame: str | None = None,
                   synth_nlos_spread: float | None = None, synth_layouts: str | None = None,
                   tag_height: float | None = None, tag_height_std: float = 0.2, no_height: bool = False,
                   turn_test: float = 0.0, mirror_test: bool = False, ensemble: int = 1, jobs: int | None = None,
                   overwrite: bool = False, progress: Callable[[str], None] | None = None) -> TrackingStudyRun:
    """The tracking study (:mod:`physynth.studies.tracking`) under a protocol (:mod:`physynth.studies.protocol`),
    its files written to the folder ``out`` (``results.json``, ``results.md``, figures): ``physynth study
    tracking`` from Python.

    Parameters
    ----------
    train, test : sequences of dataset directories, optional
        Training and test datasets (every trace one run). Neither: the default Hanyang runs
        (:func:`physynth.studies.tracking.hanyang_default_runs`; :func:`~physynth.studies.tracking_setup.load_runs`).
    scenario : preset name, scenario file, mapping or Scenario, optional
        SYNTH_PHY pre-trains on it instead of a scenario calibrated on the training runs (survey-only: all
        the study trains on).
    methods : sequence of str, optional
        Methods to run (default: the configuration file's, else all of :data:`~physynth.studies.tracking.METHODS`).
    seed, seeds : int
        Every fold runs for seeds ``seed`` .. ``seed + seeds - 1``.
    protocol : str, optional
        How runs are held out (:data:`~physynth.studies.protocol.PROTOCOLS`; default from the runs).
    quick : bool
        The quick schedule (:func:`~physynth.studies.tracking_config.quick_config`) for what is not set.
    config : path, optional
        A study configuration file (:func:`~physynth.studies.tracking_config.read_study_settings`).
    settings : mapping, optional
        :class:`~physynth.studies.tracking_config.StudyConfig` fields for this study (e.g. ``{"epochs": 40,
        "net": {"lr_schedule": "cosine"}}``); they win over the file's (``net`` merged into the file's). A
        setting that sets up methods none of which runs (:data:`~physynth.studies.tracking_setup.METHOD_SETTINGS`)
        is refused; None values count as not given.
    frame : str, optional
        How the networks see direction (:data:`~physynth.studies.tracking_setup.FRAMES`).
    synth_nlos_spread, synth_layouts : optional
        The pre-training variation's NLOS spread and layouts (:func:`~physynth.studies.tracking_setup.synth_variation`).
    tag_height, tag_height_std, no_height
        The tag height prior: given [m] with its spread, or none (default: from the training runs' truth).
    turn_test, mirror_test
        Every test run turned by ``turn_test`` degrees about its anchor centroid, mirrored first with
        ``mirror_test``.
    ensemble : int
        Score the mean of ``ensemble`` seeds' estimates (a seed ensemble).
    jobs : int, optional
        Studies (folds and seeds) run at once, each in a process of its own (default: one per CPU core), or
        with an ensemble its members trained at once (default 1). The results do not depend on it.
    progress : callable, optional
        ``progress(line)`` for every step of every study.

    Returns the :class:`~physynth.studies.tracking_setup.TrackingStudyRun`: the protocol's result, the files
    written and the studies' warnings.

    Raises
    ------
    PhySynthError
        Bad arguments (:class:`~physynth.studies.tracking_setup.TrackingArgumentError`, naming the
        parameters), an output that may not be written, datasets that cannot be read or runs unfit for the
        study, PyTorch missing for a network method.
    """
    from .studies import tracking_setup as setup
    from .studies.protocol import PROTOCOLS, plan, run_protocol
    from .studies.protocol_report import write_protocol_results
    from .studies.tracking_config import NETWORK_METHODS, StudyConfig, read_study_settings
    from .track import require_torch

    seed = check_int(seed, "seed", what="the seed")
    seeds = check_int(seeds, "seeds", minimum=1, what="the number of seeds")
    ensemble = check_int(ensemble, "ensemble", minimum=1, what="the ensemble's size")
    if jobs is not None:
        jobs = check_int(jobs, "jobs", minimum=1, what="the number of studies at once")
    given = dict(settings or {})
    odd = sorted(k for k in given if k in _PARAMETER_SETTINGS or k not in StudyConfig.__dataclass_fields__)
    if odd:
        raise setup.TrackingArgumentError(f"{{settings}}: {', '.join(odd)} not a study setting (or one given "
                                          "by a parameter of its own)")
    safety.check_study_output(out, marker="results.json", what="a tracking study", overwrite=overwrite,  # first
                              inputs=[*(train or []), *(test or [])])
    file_settings = read_study_settings(config) if config is not None else {}
    over: dict[str, Any] = {"seed": seed, **setup.frame_settings(frame)}
    net = {**file_settings.get("net", {}), **{k: v for k, v in (given.pop("net", None) or {}).items()
                                              if v is not None}}
    over |= {"methods": tuple(methods)} if methods is not None else {}
    over |= {k: v for k, v in given.items() if v is not None}
    over |= {"ensemble": ensemble} if ensemble > 1 else {}
    over |= {"jobs": jobs} if jobs is not None and jobs > 1 and ensemble > 1 else {}
    over |= setup.synth_variation(synth_nlos_spread, synth_layouts, file_settings.get("variation"))
    over |= setup.height_settings(tag_height, tag_height_std, no_height)
    over |= {"net": net} if net else {}
    cfg = setup.study_config(over, quick, None if protocol == "survey-only" else scenario, frame,  # survey-only:
                             given={"synth_nlos_spread": synth_nlos_spread, "synth_layouts": synth_layouts},
                             base=file_settings)  # the scenario is every method's
    if NETWORK_METHODS & set(cfg.methods):
        require_torch()
    if protocol is not None and protocol not in PROTOCOLS:
        raise setup.TrackingArgumentError(f"{{protocol}} must be one of {', '.join(PROTOCOLS)}, got '{protocol}'")
    if protocol == "survey-only" and scenario is None:
        raise setup.TrackingArgumentError("{protocol} survey-only needs {scenario}: the site's scenario (its "
                                          "anchors, route and channel) is all it trains on")
    train_runs, test_runs = setup.load_runs(train, test, protocol)
    scn = None if scenario is None else load_scenario(scenario)
    if turn_test or mirror_test:
        if not test_runs:
            raise setup.TrackingArgumentError("{turn_test} and {mirror_test} turn the {test} runs: give {test}")
        test_runs = setup.turned_runs(test_runs, turn_test, mirror_test)
    seed_list = list(range(seed, seed + seeds))
    _, folds, used = plan(train_runs, test_runs, protocol, seed_list, cfg)
    n_studies = len(folds) * len(used)
    if jobs is not None and jobs > 1 and ensemble == 1 and n_studies == 1:
        raise setup.TrackingArgumentError(f"{{jobs}} {jobs} runs several studies at once, and this is one study "
                                          "(one fold, one seed): give {seeds} N, or {ensemble} K to train K "
                                          "members at once")
    # with an ensemble, jobs trains its members at once; else the studies, by default one per core
    study_jobs = 1 if ensemble > 1 else jobs or min(n_studies, len(os.sched_getaffinity(0)))
    res = run_protocol(train_runs, test_runs, protocol=protocol, seeds=seed_list, scenario=scn, config=cfg,
                       jobs=study_jobs, progress=progress)
    files = setup.write_single(res, out) if len(res.studies) == 1 else write_protocol_results(res, out)
    warnings = list(dict.fromkeys(w for s in res.studies for w in s.data.get("warnings", [])))
    return setup.TrackingStudyRun(res, files, warnings)
