"""The settings of the tracking study (:mod:`physynth.studies.tracking`): every number in one frozen
:class:`StudyConfig`, the ``--quick`` schedule (:func:`quick_config`), the pre-training variation
(:data:`STUDY_VARIATION`) and a study configuration file (:func:`read_study_settings`).

A study configuration file is a YAML mapping of :class:`StudyConfig` fields (see docs/tracking.md,
"Study configuration file")::

    finetune_lr: 1.0e-4
    net: {lr_schedule: cosine}
    variation: {random_route_prob: 0.25, layout_distribution: {anchor_count: [4, 8]}}

Unknown fields and bad values are refused with the field's name before any work.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from ..errors import PhySynthError
from ..models.variation import LayoutDistribution, SiteVariationParams
from ..track.features import check_ekf_prior
from ..track.height import HeightPrior

HEIGHT_SOURCES = ("training", "scenario", "given", "none")
"""Where the study's tag height prior comes from (``StudyConfig.height``)."""

METHODS = ("NOAUG", "AUG_GAN", "SYNTH_PHY", "bilstm", "ls", "ekf")
"""Methods of the study, in table order (reference rows come last)."""
NETWORK_METHODS = frozenset({"NOAUG", "AUG_GAN", "SYNTH_PHY", "bilstm"})
"""The methods that train a network (they need PyTorch and take ``StudyConfig.net``)."""
REAL_TRAINED = ("NOAUG", "AUG_GAN", "bilstm")
"""The methods that need real training runs (SYNTH_PHY can do without: pre-training alone)."""


STUDY_LAYOUTS = LayoutDistribution(anchor_count=[4, 6], footprint_m=[2.0, 8.0], aspect=[0.25, 1.0],
                                   height_m=[0.3, 2.5], coplanar_prob=0.2, min_spacing_m=0.5, route_offset_m=[0.0, 2.0])
"""The anchor layouts of the study's pre-training traces: deployments that fix a walking tag's position, around
every layout of the Hanyang campaign (4 anchors over 1.9-5 m, aspect 0.35-0.9, heights 0.5-2 m): 4-6 anchors
(three leave the mirror image across their plane, which no tracker can tell apart), footprints of 2-8 m no
thinner than a quarter of their length (a compact or straight cluster seen from 50 m leaves the direction to
the ranges' centimetres), heights 0.3-2.5 m with a fifth of the layouts at one height (the vertical left to
the known tag height)."""


STUDY_VARIATION = SiteVariationParams(layout_distribution=STUDY_LAYOUTS, random_route_prob=0.5,
                                      path_lateral_std_m=1.0, path_sag_std_m=0.1)
"""How the study's pre-training traces vary around the calibrated site (a scenario's ``variation`` section,
:mod:`physynth.models.variation`): every trace a whole layout of :data:`STUDY_LAYOUTS`, half of them on a
random route, the run-to-run path deformation of a walker (1 m sideways, 0.1 m up and down)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StudyConfig:
    """Every number of the study (recorded in ``results.json``). Epochs are passes over the windows."""

    seed: int = 0
    quick: bool = False
    methods: tuple[str, ...] = METHODS
    epochs: int = 200
    lr: float = 1e-3
    pretrain_epochs: int = 300
    pretrain_lr: float = 1e-3
    finetune_epochs: int = 200
    finetune_lr: float = 5e-5
    n_synth_traces: int = 64
    synth_windows_per_trace: int = 64
    gan_steps: int = 3000
    gan_copies: int = 2
    finetune_synth_ratio: float = 0.0
    """SYNTH_PHY fine-tuning keeps ``ratio`` synthetic pre-training windows per real window in its
    training set (a fixed random subset, drawn from the seed); 0 fine-tunes on the real runs only."""
    net: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`~physynth.track.trackers.nets.NetConfig` for every network, by setting name
    (:data:`~physynth.track.trackers.nets.NET_SETTINGS`: its fields, and its window's by their names there,
    e.g. ``{"age_weighted_direction": False, "window_steps": 32}``)."""
    variation: SiteVariationParams = STUDY_VARIATION
    """How the synthetic pre-training traces vary around the calibrated site: every trace its own whole anchor
    layout drawn from :data:`STUDY_LAYOUTS` (each anchor the channel of one of the calibrated anchors), path
    jitter, and half of them on random routes of other shapes (:mod:`physynth.track.synth`). Without
    ``layout_distribution``: the training runs' layouts, jittered."""
    random_isometry: bool = True
    """Every network (NOAUG, AUG_GAN, SYNTH_PHY, bilstm) trains on windows turned by a random angle
    about the vertical and mirrored at random, and predicts on 8 turned copies of the test run
    (``NetConfig.random_isometry``): no direction or shape prior tied to a heading, so a run along
    another direction or of another shape is tracked (docs/tracking.md, "Runs in other directions")."""
    route_frame: bool = False
    """Every network trains and predicts in each run's own route frame (``NetConfig.route_frame``: the run
    turned so that its route heading, estimated from its own ranges, points east): a prior on the
    route's shape relative to its heading, better on runs of the training routes' shape along any
    heading, lost on a route of another shape (a loop: docs/tracking.md). Excludes ``random_isometry``.
    With both False the networks learn the compass heading of the training runs."""
    ekf_prior: str = "residual"
    """How every network uses the classical ``ekf`` run on its inputs (``NetConfig.ekf_prior``): ``residual``
    (the default) adds the network's output to the filter's position, so it learns to correct the filter;
    ``input``: one more input; ``none``: the paper's network alone (docs/tracking.md, "Measured: the
    networks correct a classical filter")."""
    training_layouts: bool = True
    train_trusted_truth: bool = False
    """The training runs' truth counts only where their recording trusts it (``track_input(...,
    trusted_truth_only=True)``): the networks are not trained on, and the ``ekf`` not fitted on, the grid
    steps inside the untrusted truth spans (the Hanyang RTK track without its fix), and the UWB lag is
    estimated on the ranges outside them. Test runs are scored as always (``rmse_m`` every step,
    ``rmse_trusted_m`` the trusted ones). Measured in docs/tracking.md: no gain, so it is off."""
    ensemble: int = 1
    """Members of a seed ensemble: the study runs once per seed ``seed``, ``seed + 1``, ...,
    ``seed + ensemble - 1`` (each a whole study: every network retrained, SYNTH_PHY on its own synthetic
    traces) and every row scores the mean of the members' estimates, step by step. ``results.json`` keeps
    each member's own rows (``data.ensemble.member_rows``). ``ensemble`` times the compute."""
    jobs: int = 1
    """Ensemble members trained at once, each in a process of its own (``threads`` PyTorch threads each):
    on a machine with cores to spare an ensemble then takes about ``ensemble / jobs`` times one study's
    wall time. The members' results do not depend on it (each is deterministic from its seed)."""
    threads: int = 1
    height: str = "training"
    """What every tracker knows of the tag's height without the ranges (:mod:`physynth.track.height`):
    ``training`` the mean and spread of the training runs' truth heights (the scenario's path without
    training runs), ``scenario`` the scenario's path, ``given`` ``tag_height_m`` +- ``tag_height_std_m``,
    ``none`` nothing (the vertical from the ranges alone)."""
    tag_height_m: float | None = None
    tag_height_std_m: float = 0.2

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise PhySynthError(f"unknown method(s) {', '.join(unknown)} (choose from {', '.join(METHODS)})")
        if not self.methods:
            raise PhySynthError("no method to run")
        check_ekf_prior(self.ekf_prior)
        if self.route_frame and self.random_isometry:
            raise PhySynthError("route_frame needs random_isometry off (random turns would remove the route "
                                "heading the frame keeps)")
        for name in ("epochs", "pretrain_epochs", "finetune_epochs", "n_synth_traces", "synth_windows_per_trace",
                     "gan_steps", "threads", "ensemble", "jobs"):
            if getattr(self, name) < 1:  # 0 epochs would report an untrained network
                raise PhySynthError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.jobs > 1 and self.ensemble == 1:
            raise PhySynthError(f"jobs {self.jobs} runs the members of an ensemble at once: it needs ensemble >= 2")
        if self.ensemble > 1 and not NETWORK_METHODS & set(self.methods):
            raise PhySynthError(f"ensemble {self.ensemble} averages the networks of several seeds, and methods "
                                f"{', '.join(self.methods)} train none (the classical trackers draw no seed): "
                                "add a network or leave ensemble at 1")
        if not 0.0 <= self.finetune_synth_ratio <= 100.0:
            raise PhySynthError(f"finetune_synth_ratio must be in [0, 100], got {self.finetune_synth_ratio}")
        if self.net and NETWORK_METHODS & set(self.methods):
            check_net_overrides(self.net)
        if self.height not in HEIGHT_SOURCES:
            raise PhySynthError(f"height must be one of {', '.join(HEIGHT_SOURCES)}, got '{self.height}'")
        if (self.height == "given") != (self.tag_height_m is not None):
            raise PhySynthError("a tag height is given exactly when height is 'given'")
        if self.height == "given":
            HeightPrior(float(self.tag_height_m), float(self.tag_height_std_m))  # refuses bad numbers

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["variation"] = self.variation.model_dump(mode="python")
        d["methods"] = list(self.methods)
        return d


def check_net_overrides(net: dict[str, Any]) -> None:
    """The ``net`` overrides checked before any work: an unknown key or a bad value fails here, not after
    the calibration (the networks are built late)."""
    from ..track.trackers.nets import NET_SETTINGS, NetConfig

    unknown = sorted(set(net) - NET_SETTINGS)
    if unknown:
        raise PhySynthError(f"unknown network setting(s) {', '.join(unknown)}")
    NetConfig.from_settings(**net)


def quick_config(**overrides: Any) -> StudyConfig:
    """The ``--quick`` schedule: fewer epochs and traces, same methods (a few minutes per study on one core).

    Five times fewer epochs than the paper's in the real-data stages, so the learning rate from scratch is
    higher (3e-3). Fine-tuning keeps the paper's gentleness: 1e-4, about a thirtieth of the from-scratch
    rate (the paper's 5e-5 is a twentieth of 1e-3); at 1e-3 the fine-tuned network learnt the training
    layout's corrections and lost 4 % against NOAUG on the held-out layout (docs/experiments.md,
    2026-12-05). Pre-training: 30 epochs on 24 windows of each of 96 synthetic traces (each trace a
    layout of its own: many traces, few windows each, for the variety of layouts at half the compute of 48
    windows). SYNTH_PHY fine-tunes on the real windows plus half as many synthetic ones
    (``finetune_synth_ratio`` 0.5).
    """
    base = {"quick": True, "epochs": 40, "lr": 3e-3, "pretrain_epochs": 30, "pretrain_lr": 3e-3,
            "finetune_epochs": 40, "finetune_lr": 1e-4, "n_synth_traces": 96, "synth_windows_per_trace": 24,
            "gan_steps": 1000, "gan_copies": 1, "finetune_synth_ratio": 0.5}
    return StudyConfig(**{**base, **overrides})


def _variation(value: Any) -> SiteVariationParams:
    """A ``variation`` setting: a :class:`SiteVariationParams`, or a mapping of the fields it changes in
    :data:`STUDY_VARIATION` (a ``layout_distribution`` mapping changes fields of :data:`STUDY_LAYOUTS`;
    null there: the training layouts, jittered)."""
    if isinstance(value, SiteVariationParams):
        return value
    if not isinstance(value, dict):
        raise PhySynthError(f"variation must be a mapping of site variation fields, got {value!r}")
    merged = {**STUDY_VARIATION.model_dump(mode="python"), **value}
    if isinstance(value.get("layout_distribution"), dict):
        merged["layout_distribution"] = {**STUDY_LAYOUTS.model_dump(mode="python"), **value["layout_distribution"]}
    try:
        return SiteVariationParams.model_validate(merged)
    except ValueError as e:  # pydantic's ValidationError: name the fields
        raise PhySynthError(f"variation: {_first_error(e)}") from None


def _first_error(e: Exception) -> str:
    errors = getattr(e, "errors", None)
    if callable(errors):
        first = errors()[0]
        return f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"
    return str(e).splitlines()[0]


def read_study_settings(path: str | os.PathLike) -> dict[str, Any]:
    """The settings of a study configuration file (module docstring), checked: a mapping of
    :class:`StudyConfig` fields, each value checked as :class:`StudyConfig` checks it.

    Raises
    ------
    PhySynthError
        The file is missing or not YAML, not a mapping, names an unknown field, or holds a bad value.
    """
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise PhySynthError(f"study configuration {p}: cannot read it ({e.strerror or e})") from None
    except yaml.YAMLError as e:
        raise PhySynthError(f"study configuration {p}: not YAML ({str(e).splitlines()[0]})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise PhySynthError(f"study configuration {p}: a mapping of study settings expected, got "
                            f"{type(data).__name__}")
    known = {f.name for f in fields(StudyConfig)} - {"quick"}
    unknown = sorted(str(k) for k in data if k not in known)
    if unknown:
        raise PhySynthError(f"study configuration {p}: unknown setting(s) {', '.join(unknown)} "
                            f"(settings: {', '.join(sorted(known))})")
    settings = dict(data)
    if "methods" in settings:
        m = settings["methods"]
        settings["methods"] = tuple(m) if isinstance(m, (list, tuple)) else tuple(str(m).split(","))
    try:
        if "variation" in settings:
            settings["variation"] = _variation(settings["variation"])
        if "net" in settings and not isinstance(settings["net"], dict):
            raise PhySynthError("net must be a mapping of network settings")
        StudyConfig(**settings)  # every value checked now, before any work
    except PhySynthError as e:
        raise PhySynthError(f"study configuration {p}: {e}") from None
    except (TypeError, ValueError) as e:
        raise PhySynthError(f"study configuration {p}: {_first_error(e)}") from None
    return settings
