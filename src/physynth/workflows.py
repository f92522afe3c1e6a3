"""Workflows: the orchestration that the command line and Python users share.

Each function reads its inputs (datasets, scenario files), runs the library and returns or writes the
result; none draws anything or knows the command line. Long ones take a ``progress`` callback
(:mod:`physynth.progress`). The command line (:mod:`physynth.cli`) is a thin layer over these.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from .calibrate import CalibrationResult, calibrate
from .calibrate._base import CalibrationError
from .constants import DEFAULT_GRID_RATE_HZ
from .errors import AnchorMismatchError, PhySynthError
from .generate import compile_scenario, dataset_meta, generate_trace, generate_traces
from .io.dataset import DatasetWriter, read_dataset
from .io.scenario_file import load_scenario
from .progress import ProgressCallback
from .records import Trace
from .rng import new_root_seed
from .scenario import Scenario, scenario_to_dict
from .validate.compare import (
    ValidationReport,
    anchor_ids,
    check_real,
    compare,
    describe_anchor_mismatch,
    transfer_record,
)


# ---------------------------------------------------------------- generate
def generate_dataset(scn: Scenario, n: int, out: str | Path, *, seed: int | None = None,
                     overwrite: bool = False, progress: ProgressCallback | None = None) -> tuple[Path, int]:
    """Generate ``n`` traces and write them as a dataset directory (atomically).

    Returns the dataset path and the root seed used (drawn from OS entropy when ``seed`` is None).
    ``progress(message, done, total)`` is called after every trace.
    """
    if n < 1:
        raise PhySynthError(f"the number of traces must be at least 1, got {n}")
    root = new_root_seed() if seed is None else int(seed)
    cs = compile_scenario(scn)
    with DatasetWriter(out, meta=dataset_meta(scn, root), overwrite=overwrite) as writer:
        for i in range(n):
            writer.add(generate_trace(cs, i, root), index=i)
            if progress is not None:
                progress(f"generating {scn.name}", i + 1, n)
    return Path(out), root


# ---------------------------------------------------------------- calibrate
def read_recordings(paths: Sequence[str | os.PathLike]) -> tuple[list[Trace], list[str]]:
    """Traces of one or several dataset directories, labelled ``<dataset>/<run or trace index>``."""
    if not paths:
        raise CalibrationError("no dataset directories given")
    traces, sources = [], []
    for p in paths:
        ds = read_dataset(p)
        sources.append(str(Path(p)))
        for i, t in enumerate(ds.traces):
            lab = f"{Path(p).name}/{t.meta.get('run') or f'trace {i}'}"
            traces.append(Trace(truth=t.truth, uwb=t.uwb, anchors=t.anchors, imu=t.imu,
                                meta={**t.meta, "label": lab}))
    return traces, sources


def calibrate_datasets(paths: Sequence[str | os.PathLike], **kwargs: Any) -> CalibrationResult:
    """:func:`calibrate` on every trace of one or several dataset directories, pooled."""
    traces, sources = read_recordings(paths)
    return calibrate(traces, sources=sources, **kwargs)


# ---------------------------------------------------------------- validate
def _read(reader: Callable[[str | Path], Any], path: str | Path, role: str) -> Any:
    """Read a dataset; its one-line error names the role (real or synthetic)."""
    try:
        return reader(path)
    except PhySynthError as exc:
        raise PhySynthError(f"{role} dataset: {exc}") from None
    except ValueError as exc:  # a table that reads but does not make valid records (unsorted times, ...)
        raise PhySynthError(f"{role} dataset {path}: invalid content: {exc}") from None


def validate_datasets(real: str | Path, *, synthetic: str | Path | None = None,
                      scenario: str | Path | Scenario | None = None,
                      n: int = 50, seed: int | None = None, transfer: bool = False,
                      rate_hz: float = DEFAULT_GRID_RATE_HZ,
                      progress: ProgressCallback | None = None) -> ValidationReport:
    """Validate a real dataset against a synthetic dataset or against traces generated from a scenario.

    Parameters
    ----------
    real : path
        Dataset directory of real traces (with ground truth).
    synthetic : path, optional
        Dataset directory of synthetic traces. Exactly one of ``synthetic`` and ``scenario``.
    scenario : str, path or Scenario, optional
        Preset name, scenario file or object; ``n`` traces are generated from root seed ``seed``
        (drawn from OS entropy and recorded when None).
    transfer : bool
        Take path geometry, motion and anchor layout from the real dataset
        (:func:`physynth.calibrate.transfer_scenario`) and keep every sensor, channel and
        availability parameter of the scenario (paper section IV.C). Needs ``scenario``.
    rate_hz : float
        Evaluation grid rate [Hz].
    progress : callable, optional
        ``progress(message, done, total)`` after each synthetic trace is generated and reduced.

    Raises
    ------
    PhySynthError
        One line for every kind of bad input: both or neither of ``synthetic``/``scenario``,
        ``transfer`` without a scenario, ``n < 1``, unreadable or empty datasets, a real dataset
        without truth, anchors or valid ranges, and anchor ids that differ (without ``transfer``).
    """

    if (synthetic is None) == (scenario is None):
        raise PhySynthError("give exactly one of a synthetic dataset and a scenario "
                            f"({'both' if synthetic is not None else 'neither'} given)")
    if transfer and scenario is None:
        raise PhySynthError("transfer needs a scenario (it builds a scenario for the real run's geometry)")
    if scenario is not None and n < 1:
        raise PhySynthError(f"-n must be at least 1, got {n}")
    real_ds = _read(read_dataset, real, "real")
    real_traces = real_ds.traces
    from .validate.imu_report import is_imu_only

    if is_imu_only(real_traces):  # IMU recordings without UWB: IMU error statistics only
        return _validate_imu(real, real_ds, synthetic=synthetic, scenario=scenario, n=n, seed=seed,
                             transfer=transfer, progress=progress)
    check_real(real_traces, f"real dataset {real}")
    real_ids = anchor_ids(real_traces)
    inputs: dict[str, Any] = {"real": {"path": str(real), "kind": real_ds.meta.get("kind"),
                                       "source": real_ds.meta.get("source"), "anchors": real_ids}}
    transfer_info = None

    if synthetic is not None:
        synth_ds = _read(read_dataset, synthetic, "synthetic")
        synth_ids = anchor_ids(synth_ds.traces)
        problem = describe_anchor_mismatch(real_ids, synth_ids, f"the synthetic dataset {synthetic}")
        if problem:
            raise AnchorMismatchError(problem)
        if not any(s.uwb.valid.any() for s in synth_ds.traces):
            raise PhySynthError(f"synthetic dataset {synthetic} has no valid UWB range: nothing to compare")
        inputs["synthetic"] = {"path": str(synthetic), "kind": synth_ds.meta.get("kind"),
                               "scenario_name": synth_ds.meta.get("scenario_name"),
                               "root_seed": synth_ds.meta.get("root_seed"), "n_traces": len(synth_ds)}
        synth_iter: Iterable[Trace] = synth_ds.traces
        total = len(synth_ds)
    else:
        scn = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        source = scn.name if isinstance(scenario, Scenario) else str(scenario)
        if transfer:
            try:
                from .calibrate import transfer_scenario
            except ImportError as exc:
                raise PhySynthError(f"transfer is not available in this install ({exc})") from None
            original = scn
            scn = transfer_scenario(original, real_traces)
            transfer_info = transfer_record(original, scn, str(real), real_ids)
        else:
            problem = describe_anchor_mismatch(real_ids, list(scn.anchor_ids), f"scenario '{scn.name}'")
            if problem:
                raise AnchorMismatchError(problem + "; transfer the scenario to take the anchor layout from the "
                                                    "real dataset")
        root = new_root_seed() if seed is None else int(seed)
        inputs["synthetic"] = {"scenario": source, "scenario_name": scn.name, "n_traces": int(n),
                               "root_seed": root, "transfer": bool(transfer),
                               "scenario_config": scenario_to_dict(scn)}
        synth_iter = generate_traces(compile_scenario(scn), n, seed=root)
        total = n

    if progress is None:
        return compare(real_traces, synth_iter, rate_hz=rate_hz, inputs=inputs, transfer=transfer_info)
    verb = "generating + reducing" if synthetic is None else "reducing"
    done = 0

    def on_trace() -> None:
        nonlocal done
        done += 1
        progress(f"{verb} synthetic traces", done, total)

    progress(f"{verb} synthetic traces", 0, total)
    return compare(real_traces, synth_iter, rate_hz=rate_hz, inputs=inputs, transfer=transfer_info, on_trace=on_trace)


def _validate_imu(real: str | Path, real_ds: Any, *, synthetic: str | Path | None,
                  scenario: str | Path | Scenario | None, n: int, seed: int | None, transfer: bool,
                  progress: ProgressCallback | None) -> Any:
    """:func:`validate_datasets` for IMU-only real data (:mod:`physynth.validate.imu_report`)."""
    from .validate.imu_report import validate_imu

    inputs: dict[str, Any] = {"real": {"path": str(real), "kind": real_ds.meta.get("kind"),
                                       "imu_frames": real_ds.meta.get("imu_frames")}}
    if synthetic is not None:
        synth_ds = _read(read_dataset, synthetic, "synthetic")
        inputs["synthetic"] = {"path": str(synthetic), "n_traces": len(synth_ds)}
        return validate_imu(real_ds.traces, synthetic=synth_ds.traces, inputs=inputs)
    scn = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    return validate_imu(real_ds.traces, scenario=scn, n=n, seed=seed, transfer=transfer, inputs=inputs,
                        progress=progress)
