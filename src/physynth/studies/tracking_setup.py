"""The rules that set up a tracking study from what its caller gives (:func:`physynth.workflows.tracking_study`,
``physynth study tracking``): which settings apply to which methods, how the networks see direction
(:data:`FRAMES`), the pre-training variation and tag height asked for, which runs train and test
(:func:`load_runs`: the datasets given or the default Hanyang runs), turned test runs, and one study's files
(:func:`write_single`).

Errors about the arguments are :class:`TrackingArgumentError` s: their message names the parameters, and
:meth:`TrackingArgumentError.worded` says the same with other names for them (the command line's options).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import ArgumentError
from .tracking_config import METHODS, NETWORK_METHODS, StudyConfig, quick_config

FRAMES = {"route": {"route_frame": True, "random_isometry": False},
          "turned": {"route_frame": False, "random_isometry": True},
          "compass": {"route_frame": False, "random_isometry": False}}
"""How the networks may see direction (``frame``) and the study settings each one stands for."""

SYNTH_LAYOUTS = ("drawn", "training")
"""``synth_layouts`` choices: each synthetic pre-training trace a layout of its own (the study's variation), or
the training runs' layouts, jittered."""

NETWORKS = tuple(m for m in METHODS if m in NETWORK_METHODS)
"""The network methods, in table order."""
_SYNTH = ("SYNTH_PHY",)
METHOD_SETTINGS: dict[str, tuple[str, ...]] = {
    "epochs": ("NOAUG", "AUG_GAN", "bilstm"), "scenario": _SYNTH, "pretrain_epochs": _SYNTH,
    "finetune_epochs": _SYNTH, "n_synth_traces": _SYNTH, "synth_windows_per_trace": _SYNTH,
    "finetune_synth_ratio": _SYNTH, "ekf_prior": NETWORKS, "lr_schedule": NETWORKS, "weight_average": NETWORKS,
    "frame": NETWORKS, "ensemble": NETWORKS, "synth_nlos_spread": _SYNTH, "synth_layouts": _SYNTH}
"""Settings (study settings, network settings and parameters of the study) that set up some methods only, with
those methods: given for a study that runs none of them, a setting is refused, not silently ignored. ``frame``
sets up how the networks see direction; ``ensemble`` averages seeds, and the classical trackers draw none. A
configuration file's settings are not refused."""

PARAMETERS = frozenset({*METHOD_SETTINGS, "methods", "train", "test", "protocol", "turn_test", "mirror_test",
                        "tag_height", "no_height", "jobs", "seeds", "settings"})
"""The parameters the messages of :class:`TrackingArgumentError` name (as ``{name}`` in its template)."""


class TrackingArgumentError(ArgumentError):
    """A bad or unused argument of a tracking study. ``template`` is the message with each parameter it names
    written ``{name}`` (a name of :data:`PARAMETERS`); the message itself names the parameters as they are."""

    def __init__(self, template: str) -> None:
        self.template = template
        super().__init__(self.worded({}))

    def worded(self, names: Mapping[str, str]) -> str:
        """The message with the parameters called by ``names`` (``{"methods": "--methods"}``; a parameter
        left out keeps its own name)."""
        return re.sub(r"\{(\w+)\}", lambda m: names.get(m[1], m[1]) if m[1] in PARAMETERS else m[0],
                      self.template)


def _value(v: Any) -> str:
    """A value put into a template: its braces cannot read as a parameter."""
    return str(v).replace("{", "(").replace("}", ")")


def study_config(over: Mapping[str, Any], quick: bool, scenario: Any = None, frame: str | None = None,
                 given: Mapping[str, Any] | None = None, base: Mapping[str, Any] | None = None) -> StudyConfig:
    """The study's configuration from the settings given for this study (``over``), over those of a
    configuration file (``base``); ``quick``: the quick schedule for the rest (:func:`quick_config`). A
    setting of :data:`METHOD_SETTINGS` given when none of the methods it sets up runs is refused (``given``:
    the parameters given that are not settings of their own, such as the parts of ``variation``; ``scenario``
    and ``frame`` as given); a file's settings are not refused. ``ensemble`` and ``jobs`` are checked last."""

    def make(settings: Mapping[str, Any]) -> StudyConfig:
        merged = {**(base or {}), **settings}
        return quick_config(**merged) if quick else StudyConfig(**merged)

    # bad values first, then settings without use, then the ensemble's own settings
    cfg = make({k: v for k, v in over.items() if k not in ("ensemble", "jobs")})
    named = {**over, **over.get("net", {}), "scenario": scenario, "frame": frame, **(given or {})}
    for name, users in METHOD_SETTINGS.items():
        if named.get(name) is not None and not set(users) & set(cfg.methods):
            which = users[0] if len(users) == 1 else f"{', '.join(users[:-1])} or {users[-1]}"
            raise TrackingArgumentError(
                f"{{{name}}} only matters for {which}, which {{methods}} leaves out ({','.join(cfg.methods)}): add "
                f"{'it' if len(users) == 1 else 'one'} or leave {{{name}}} out")
    return make(over)


def frame_settings(frame: str | None) -> dict[str, Any]:
    """The study settings of ``frame`` (:data:`FRAMES`; None: {})."""
    if frame is not None and frame not in FRAMES:
        raise TrackingArgumentError(f"{{frame}} must be one of {', '.join(FRAMES)}, got '{_value(frame)}'")
    return dict(FRAMES.get(frame, {}))


def synth_variation(nlos_spread: float | None, layouts: str | None = None, base: Any = None) -> dict[str, Any]:
    """The study's pre-training variation (``base``, a configuration file's, else the default) with the NLOS
    spread ``nlos_spread`` and the layouts ``layouts`` (:data:`SYNTH_LAYOUTS`) as a study setting ({} when
    neither is given)."""
    if nlos_spread is None and layouts is None:
        return {}
    if layouts not in (None, *SYNTH_LAYOUTS):
        raise TrackingArgumentError(f"{{synth_layouts}} must be one of {', '.join(SYNTH_LAYOUTS)}, got "
                                    f"'{_value(layouts)}'")
    v = base if base is not None else StudyConfig().variation
    if nlos_spread is not None:
        v = v.model_copy(update={"nlos_log_std": nlos_spread})
    if layouts == "training":
        v = v.model_copy(update={"layout_distribution": None})
    return {"variation": v}


def height_settings(tag_height: float | None, tag_height_std: float, no_height: bool) -> dict[str, Any]:
    """The study's height settings: a tag height given (``tag_height`` +- ``tag_height_std`` [m]), none
    (``no_height``) or, with neither, {} (the study's default)."""
    if no_height and tag_height is not None:
        raise TrackingArgumentError("{no_height} and {tag_height} exclude each other")
    if no_height:
        return {"height": "none"}
    if tag_height is None:
        return {}
    return {"height": "given", "tag_height_m": tag_height, "tag_height_std_m": tag_height_std}


def load_runs(train: Sequence[str | os.PathLike] | None, test: Sequence[str | os.PathLike] | None,
              protocol: str | None) -> tuple[list, list]:
    """The runs and the test runs (:class:`~physynth.studies.tracking.StudyRun` s): every trace of the
    datasets given, or the default Hanyang runs (all four, held out by the protocol; the split protocol
    trains on the first three and tests on the last; survey-only tests on them all)."""
    from .tracking import hanyang_default_runs, runs_from_dataset

    def runs(paths: Sequence[str | os.PathLike] | None) -> list:
        return [r for p in paths or [] for r in runs_from_dataset(p)]

    if protocol == "survey-only":
        if train:
            raise TrackingArgumentError("{protocol} survey-only trains on no real run: leave {train} out")
        if test:
            return [], runs(test)
        train_runs, test_run = hanyang_default_runs()
        return [], [*train_runs, test_run]
    if test and not train:
        raise TrackingArgumentError("{test} needs {train} (or {protocol} survey-only with {scenario})")
    if train:
        if protocol == "split" and not test:
            raise TrackingArgumentError("{protocol} split trains on {train} and scores {test}: give {test}")
        return runs(train), runs(test)
    train_runs, test_run = hanyang_default_runs()
    if protocol == "split":
        return train_runs, [test_run]
    return [*train_runs, test_run], []


def turned_runs(runs: Sequence, turn_deg: float, mirror: bool) -> list:
    """The runs turned by ``turn_deg`` degrees (counter-clockwise) about the vertical through their anchor
    centroids, mirrored first (y -> -y) with ``mirror``; their labels say so."""
    from ..transform import turn_trace

    if not math.isfinite(turn_deg):
        raise TrackingArgumentError(f"{{turn_test}} must be a finite angle in degrees, got {turn_deg}")
    how = f"turned {turn_deg:g} deg" + (", mirrored" if mirror else "")
    return [dataclasses.replace(r, label=f"{r.label} ({how})",
                                trace=turn_trace(r.trace, math.radians(turn_deg), mirror=mirror)) for r in runs]


def write_single(res: Any, out: str | os.PathLike) -> dict[str, Path]:
    """One study's files (:func:`physynth.studies.tracking_report.write_results`) with the per-run table of
    the protocol result ``res`` in ``results.json`` (``protocol``) and ``results.md``."""
    import json

    from ..io.atomic import atomic_write_text
    from .protocol_report import protocol_markdown
    from .tracking_report import write_results

    files = write_results(res.studies[0], out)
    data = json.loads(files["json"].read_text())
    data["protocol"] = {k: v for k, v in res.to_json().items() if k != "config"}
    atomic_write_text(files["json"], json.dumps(data, indent=1, allow_nan=True) + "\n")
    atomic_write_text(files["md"], files["md"].read_text() + "\n" + protocol_markdown(res))
    return files


@dataclasses.dataclass(frozen=True, slots=True)
class TrackingStudyRun:
    """What :func:`physynth.workflows.tracking_study` did: the protocol's result, the files written and the
    studies' warnings (each once)."""

    result: Any
    """The :class:`~physynth.studies.protocol.ProtocolResult` (``result.studies``: one per fold and seed)."""
    files: dict[str, Path]
    warnings: list[str]

    @property
    def single(self) -> bool:
        """One study (one fold, one seed): its own table was written, with the per-run table beside it."""
        return len(self.result.studies) == 1
