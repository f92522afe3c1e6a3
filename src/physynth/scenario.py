"""Scenarios: everything a generator needs, as a validated, frozen object and a YAML file.

A scenario holds the path, motion, IMU, UWB acquisition, anchor layout, per-anchor channel
parameters and availability. Built-in presets are YAML files shipped in ``physynth/presets``; a
calibrated scenario is written in the same format, so ``calibrate`` output feeds ``generate``.

Loading validates every field; a bad file gives one :class:`~physynth.errors.ScenarioError` line that
names the file, the field and the reason.
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import ScenarioError

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", strict=False)


# ---------------------------------------------------------------- path
class PerturbationParams(_Model):
    """Run-to-run cable deformation that keeps both end stations fixed (a half-sine along the path)."""

    lateral_std_m: NonNegFloat = 2.0
    sag_std_m: NonNegFloat = 1.0


class PathParams(_Model):
    """Geometry p(s), s in [0, length_m], in ENU metres.

    ``polynomial``: ``coeffs_enu_m`` holds three power-series coefficient lists (E, N, U, lowest order
    first) in the normalised arc length u = s / length_m (the paper fits degree 10 to GNSS truth).
    ``waypoints``: a smooth cubic spline through ``waypoints_enu_m``, re-parameterised by arc length.
    ``reverse`` travels the path from its end to its start (e.g. the ascending run of a cable car).
    """

    kind: Literal["polynomial", "waypoints"]
    length_m: PositiveFloat | None = None
    coeffs_enu_m: list[list[FiniteFloat]] | None = None
    waypoints_enu_m: list[Vec3] | None = None
    reverse: bool = False
    perturbation: PerturbationParams = PerturbationParams()

    @model_validator(mode="after")
    def _check_kind(self) -> PathParams:
        if self.kind == "polynomial":
            if self.coeffs_enu_m is None or self.length_m is None:
                raise ValueError("a polynomial path needs length_m and coeffs_enu_m")
            if len(self.coeffs_enu_m) != 3 or not all(len(c) >= 2 for c in self.coeffs_enu_m):
                raise ValueError("coeffs_enu_m needs three coefficient lists (E, N, U) of length >= 2")
        else:
            if self.waypoints_enu_m is None or len(self.waypoints_enu_m) < 2:
                raise ValueError("a waypoints path needs at least 2 waypoints_enu_m")
            w = np.asarray(self.waypoints_enu_m)
            if np.any(np.linalg.norm(np.diff(w, axis=0), axis=1) <= 0):
                raise ValueError("waypoints_enu_m has two consecutive identical waypoints")
        return self


# ---------------------------------------------------------------- motion
class SpeedProfileParams(_Model):
    """Shape g(u) of the speed over normalised trip time u in [0, 1], scaled so max g = 1.

    ``trapezoid``: accelerate over ``accel_frac`` of the trip, cruise, decelerate over ``decel_frac``
    (raised-cosine ramps, so acceleration is continuous). ``polynomial``: power-series coefficients
    in u (the paper fits degree 4 to the real speed). ``empirical``: ``samples`` of g at equally
    spaced u (calibration uses it when a polynomial fits poorly), smoothed before differentiation by
    a smoothing spline over u in [0, 1] with penalty ``smoothing`` (``lam`` of
    scipy.interpolate.make_smoothing_spline; smaller keeps more detail, e.g. the stops of a walk).
    """

    kind: Literal["trapezoid", "polynomial", "empirical"] = "trapezoid"
    accel_frac: Probability = 0.15
    decel_frac: Probability = 0.15
    coeffs: list[FiniteFloat] | None = None
    samples: list[NonNegFloat] | None = None
    smoothing: PositiveFloat = 1e-5

    @model_validator(mode="after")
    def _check(self) -> SpeedProfileParams:
        if self.kind == "trapezoid" and self.accel_frac + self.decel_frac > 1:
            raise ValueError("accel_frac + decel_frac must not exceed 1")
        if self.kind == "polynomial" and not self.coeffs:
            raise ValueError("a polynomial speed profile needs coeffs")
        if self.kind == "empirical" and (not self.samples or len(self.samples) < 3):
            raise ValueError("an empirical speed profile needs at least 3 samples")
        return self


class MotionParams(_Model):
    """Trip kinematics: cruise speed, per-run spread (uniform +-frac), rests at the stations."""

    cruise_speed_mps: PositiveFloat
    profile: SpeedProfileParams = SpeedProfileParams()
    cruise_speed_spread_frac: Annotated[float, Field(ge=0, lt=1)] = 0.12
    length_spread_frac: Annotated[float, Field(ge=0, lt=1)] = 0.05
    dwell_start_s: NonNegFloat = 0.0
    dwell_end_s: NonNegFloat = 0.0


# ---------------------------------------------------------------- IMU
class VibrationParams(_Model):
    """Band-limited vibration: narrow-band noise at ``fundamental_hz`` and harmonics.

    ``amplitude_mps2`` is the RMS per axis of the whole vibration, times ``axis_gain`` (E, N, U) where
    the axes vibrate unequally; ``harmonic_weights`` split its variance between the fundamental and
    its harmonics; ``bandwidth_hz`` is the -3 dB width of
    each spectral line.
    """

    fundamental_hz: PositiveFloat = 2.8
    amplitude_mps2: NonNegFloat = 0.12
    harmonic_weights: list[NonNegFloat] = Field(default=[1.0, 0.5, 0.25], min_length=1)
    bandwidth_hz: PositiveFloat = 0.3
    axis_gain: Annotated[list[NonNegFloat], Field(min_length=3, max_length=3)] = [1.0, 1.0, 1.0]


class ImuParams(_Model):
    """Accelerometer in ENU, gravity-free [m s^-2].

    White noise of density ``white_noise_density_mps2_per_sqrt_hz`` per axis (per-sample standard
    deviation density * sqrt(rate_hz)); bias random walk whose standard deviation grows as
    ``bias_rw_mps2_per_sqrt_s`` * sqrt(t); vibration as above.
    """

    rate_hz: PositiveFloat = 400.0
    white_noise_density_mps2_per_sqrt_hz: Vec3 = [0.161, 0.086, 0.106]
    bias_rw_mps2_per_sqrt_s: NonNegFloat = 0.002
    bias_initial_std_mps2: NonNegFloat = 0.0
    vibration: VibrationParams = VibrationParams()


# ---------------------------------------------------------------- UWB
class NlosMode(_Model):
    """One Gaussian component of the NLOS range offset delta [m].

    ``weight`` is the share of NLOS measurements in this mode. An NLOS episode keeps one mode (one
    reflector) for its whole length, of mean ``dwell_s`` (default: ``uwb.nlos_dwell_s``).
    """

    weight: PositiveFloat
    mean_m: FiniteFloat
    std_m: PositiveFloat
    dwell_s: PositiveFloat | None = None


class NlosZone(_Model):
    """A stretch of path (e.g. around a support pylon) where NLOS probability rises."""

    s_m: NonNegFloat
    half_width_m: PositiveFloat
    nlos_prob: Probability
    label: str = "pylon"


class ChannelParams(_Model):
    """Ranging channel of one anchor: LOS Gaussian, NLOS mixture, effective rate and link range."""

    rate_hz: PositiveFloat = 18.5
    los_mean_m: FiniteFloat = 0.0
    los_std_m: PositiveFloat = 0.1
    range_bias_per_m: FiniteFloat = 0.0
    nlos_prob: Probability = 0.0
    nlos_modes: list[NlosMode] = Field(default=[NlosMode(weight=1.0, mean_m=1.0, std_m=0.5)], min_length=1)
    max_range_m: PositiveFloat = 300.0
    edge_width_m: PositiveFloat = 5.0


class ChannelOverride(_Model):
    """Per-anchor changes to the default channel; fields left out keep the default."""

    rate_hz: PositiveFloat | None = None
    los_mean_m: FiniteFloat | None = None
    los_std_m: PositiveFloat | None = None
    range_bias_per_m: FiniteFloat | None = None
    nlos_prob: Probability | None = None
    nlos_modes: list[NlosMode] | None = None
    max_range_m: PositiveFloat | None = None
    edge_width_m: PositiveFloat | None = None


class AvailabilityParams(_Model):
    """Per-anchor per-burst dropout, outage onset per burst, outage durations [s].

    ``tag_outage_*`` is an optional outage process of the tag itself (antenna shadowed by the carrier,
    radio reset): while it lasts no anchor is heard. Real recordings show such all-anchor gaps
    (Hanyang LOS Case_2 loses every anchor for ~22 s); per-anchor outages alone cannot make them.
    """

    dropout_prob: Probability = 0.04
    outage_onset_prob: Probability = 0.003
    outage_mean_s: PositiveFloat = 16.0
    tag_outage_onset_prob: Probability = 0.0
    tag_outage_mean_s: PositiveFloat = 16.0
    start_stationary: bool = True


class AvailabilityOverride(_Model):
    dropout_prob: Probability | None = None
    outage_onset_prob: Probability | None = None
    outage_mean_s: PositiveFloat | None = None


class UwbParams(_Model):
    """Burst-based acquisition shared by all anchors.

    The tag ranges in bursts near ``burst_rate_hz`` (period jitter ``burst_jitter_s``); within a burst
    anchor j is ranged ``j * slot_s`` after the burst start, and only with probability
    rate_hz / burst_rate_hz (effective per-anchor rate). Stamps lag true time by ``time_offset_s``.
    The bursts are locked to the tag clock; ``burst_phase_s`` is the stamp time of the first burst
    after the trace start, modulo the period (``None``: drawn uniformly per trace, the usual choice for
    training data; a number: a recording's own alignment, which decides how often a burst straddles
    two 10 ms grid bins and so the grid availability metrics).
    NLOS episodes last ``nlos_dwell_s`` on average.
    """

    burst_rate_hz: PositiveFloat = 23.0
    burst_jitter_s: NonNegFloat = 0.003
    burst_phase_s: NonNegFloat | None = None
    slot_s: NonNegFloat = 0.0015
    time_offset_s: FiniteFloat = 0.0
    nlos_dwell_s: PositiveFloat = 0.5
    zones: list[NlosZone] = []


class AnchorSpec(_Model):
    id: Annotated[str, Field(min_length=1)]
    pos_enu_m: Vec3
    name: str | None = None


class Scenario(_Model):
    """A complete generator configuration (DESIGN.md section 4)."""

    name: Annotated[str, Field(min_length=1)]
    description: str = ""
    path: PathParams
    motion: MotionParams
    imu: ImuParams = ImuParams()
    uwb: UwbParams = UwbParams()
    anchors: list[AnchorSpec] = Field(min_length=1)
    channel: ChannelParams = ChannelParams()
    channel_per_anchor: dict[str, ChannelOverride] = {}
    availability: AvailabilityParams = AvailabilityParams()
    availability_per_anchor: dict[str, AvailabilityOverride] = {}
    truth_rate_hz: PositiveFloat = 100.0
    grid_rate_hz: PositiveFloat = 100.0
    provenance: dict[str, Any] = {}

    @field_validator("anchors")
    @classmethod
    def _unique_ids(cls, anchors: list[AnchorSpec]) -> list[AnchorSpec]:
        ids = [a.id for a in anchors]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"duplicate anchor id(s) {dup}")
        return anchors

    @model_validator(mode="after")
    def _check_refs(self) -> Scenario:
        ids = {a.id for a in self.anchors}
        for field_name in ("channel_per_anchor", "availability_per_anchor"):
            unknown = sorted(set(getattr(self, field_name)) - ids)
            if unknown:
                raise ValueError(f"{field_name} names unknown anchor(s) {unknown}; "
                                 f"the anchors are {sorted(ids)}")
        for a in self.anchors:
            if self.channel_for(a.id).rate_hz > self.uwb.burst_rate_hz * (1 + 1e-9):
                raise ValueError(f"anchor {a.id}: rate_hz exceeds uwb.burst_rate_hz")
        return self

    # resolved per-anchor parameters
    def channel_for(self, anchor_id: str) -> ChannelParams:
        over = self.channel_per_anchor.get(anchor_id)
        if over is None:
            return self.channel
        return ChannelParams.model_validate({**self.channel.model_dump(), **over.model_dump(exclude_none=True)})

    def availability_for(self, anchor_id: str) -> AvailabilityParams:
        over = self.availability_per_anchor.get(anchor_id)
        if over is None:
            return self.availability
        return AvailabilityParams.model_validate({**self.availability.model_dump(),
                                                **over.model_dump(exclude_none=True)})

    @property
    def anchor_ids(self) -> tuple[str, ...]:
        return tuple(a.id for a in self.anchors)


# ---------------------------------------------------------------- loading
PRESET_DIR = "presets"


def list_presets() -> list[str]:
    """Names of the built-in scenario presets."""
    files = resources.files("physynth").joinpath(PRESET_DIR).iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith(".yaml"))


def _format_validation_error(err: ValidationError, source: str) -> str:
    e = err.errors()[0]
    loc = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in e["loc"]).replace(".[", "[")
    msg = e["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    got = e.get("input")
    shown = "" if isinstance(got, (dict, list)) or e["type"] == "missing" else f" (got {got!r})"
    where = f"field {loc}: " if loc else ""
    more = f" [+{len(err.errors()) - 1} more]" if len(err.errors()) > 1 else ""
    return f"scenario {source}: {where}{msg}{shown}{more}"


def scenario_from_dict(data: Any, source: str = "<dict>") -> Scenario:
    """Validate a mapping as a Scenario; raise ScenarioError with one clear line on bad input."""
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario {source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as err:
        raise ScenarioError(_format_validation_error(err, source)) from None


def _nan_guard(obj: Any, where: str = "") -> None:
    """YAML ``.nan``/``.inf`` anywhere (including free-form provenance) is refused early and clearly."""
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ScenarioError(f"field {where or '<top>'}: must be a finite number (got {obj})")
    if isinstance(obj, dict):
        for k, v in obj.items():
            _nan_guard(v, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _nan_guard(v, f"{where}[{i}]")


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A preset by name, or a scenario YAML file by path."""
    text: str
    source = str(name_or_path)
    p = Path(name_or_path)
    if str(name_or_path) in list_presets():
        text = resources.files("physynth").joinpath(PRESET_DIR, f"{name_or_path}.yaml").read_text("utf-8")
        source = f"preset '{name_or_path}'"
    elif p.suffix.lower() in (".yaml", ".yml", ".json") or p.exists():
        if p.is_dir():
            raise ScenarioError(f"scenario {p} is a directory, not a scenario file")
        if not p.is_file():
            raise ScenarioError(f"scenario file {p} does not exist")
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ScenarioError(f"cannot read scenario file {p}: {exc}") from None
    else:
        raise ScenarioError(f"unknown scenario '{name_or_path}': not a preset ({', '.join(list_presets())}) "
                            "and not a file")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"scenario {source}: not valid YAML{at}") from None
    try:
        _nan_guard(data)
    except ScenarioError as exc:
        raise ScenarioError(f"scenario {source}: {exc}") from None
    return scenario_from_dict(data, source)


def scenario_to_dict(scn: Scenario) -> dict[str, Any]:
    return scn.model_dump(mode="json", exclude_defaults=False)


def scenario_to_yaml(scn: Scenario) -> str:
    return yaml.safe_dump(scenario_to_dict(scn), sort_keys=False, default_flow_style=None, width=100)


def save_scenario(scn: Scenario, path: str | Path, header: str = "") -> Path:
    """Write a scenario as YAML, atomically."""
    from .io.dataset import atomic_write_text

    text = "".join(f"# {line}\n" for line in header.splitlines()) + scenario_to_yaml(scn)
    atomic_write_text(Path(path), text)
    return Path(path)
