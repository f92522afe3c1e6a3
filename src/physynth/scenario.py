"""Scenarios: the composition of every model's parameters into one validated, frozen object.

A scenario holds the path, motion, IMU, UWB acquisition, anchor layout, per-anchor channel
parameters and availability. Each part's class belongs to its model (:mod:`physynth.models`); this
module composes them, resolves per-anchor overrides and converts a scenario to and from a plain
mapping. Files (YAML, presets) are read and written by :mod:`physynth.io.scenario_file`.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from .constants import IMU_BODY_FRAME, IMU_FRAME
from .errors import ScenarioError
from .field_bounds import check_bounds
from .models._params import ParamsModel, PositiveFloat
from .models.attitude import AttitudeParams
from .models.availability import AvailabilityOverride, AvailabilityParams
from .models.imu import AccelerometerParams, BodyImuParams, GyroscopeParams, ImuParams, VibrationParams
from .models.motion import MotionParams, SpeedProfileParams
from .models.obstacles import BoxObstacle, PrismObstacle, TerrainGrid, WallObstacle
from .models.path import PathParams, PerturbationParams
from .models.uwb import AnchorSpec, ChannelOverride, ChannelParams, LinkBudgetParams, NlosMode, NlosZone, UwbParams
from .models.variation import SiteVariationParams

__all__ = ["AccelerometerParams", "AnchorSpec", "AttitudeParams", "AvailabilityOverride", "AvailabilityParams",
           "BodyImuParams", "BoxObstacle", "ChannelOverride", "ChannelParams", "GyroscopeParams", "ImuParams",
           "LinkBudgetParams", "MotionParams", "NlosMode", "NlosZone", "PathParams", "PerturbationParams",
           "PrismObstacle", "Scenario", "SiteVariationParams", "SpeedProfileParams", "TerrainGrid", "UwbParams",
           "VibrationParams", "WallObstacle", "scenario_from_dict", "scenario_to_dict"]


class Scenario(ParamsModel):
    """A complete generator configuration: every model's parameters, the anchors and the rates."""

    name: Annotated[str, Field(min_length=1)]
    description: str = ""
    path: PathParams
    motion: MotionParams
    attitude: AttitudeParams = AttitudeParams()
    imu: ImuParams = ImuParams()
    body_imu: BodyImuParams = BodyImuParams()
    imu_frames: Annotated[list[Literal["enu-gravity-free", "body-flu"]], Field(min_length=1)] = [IMU_FRAME]
    uwb: UwbParams = UwbParams()
    anchors: list[AnchorSpec]  # required; an explicit [] is an IMU-only scenario (no UWB rows)
    channel: ChannelParams = ChannelParams()
    channel_per_anchor: dict[str, ChannelOverride] = {}
    availability: AvailabilityParams = AvailabilityParams()
    availability_per_anchor: dict[str, AvailabilityOverride] = {}
    truth_rate_hz: PositiveFloat = 100.0
    grid_rate_hz: PositiveFloat = 100.0
    variation: SiteVariationParams | None = None  # per-trace anchor layout and path; None: one site
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
        if len(set(self.imu_frames)) != len(self.imu_frames):
            raise ValueError(f"imu_frames lists a frame twice: {self.imu_frames}")
        if (IMU_FRAME in self.imu_frames and IMU_BODY_FRAME in self.imu_frames
                and abs(self.imu.rate_hz - self.body_imu.rate_hz) > 1e-9 * self.imu.rate_hz):
            raise ValueError(f"both IMU frames share one time base: imu.rate_hz ({self.imu.rate_hz}) and "
                             f"body_imu.rate_hz ({self.body_imu.rate_hz}) must be equal")
        if self.variation is not None:
            if self.variation.layout_distribution is not None and not self.anchors:
                raise ValueError("variation.layout_distribution needs anchors: each drawn anchor takes the channel "
                                 "and availability of one of the scenario's anchors")
            for k, lay in enumerate(self.variation.layouts):
                if len(lay) != len(self.anchors):
                    raise ValueError(f"variation.layouts[{k}] holds {len(lay)} position(s) for "
                                     f"{len(self.anchors)} anchor(s): one [E, N, U] per anchor, in anchor order")
        for a in self.anchors:
            if self.channel_for(a.id).rate_hz > self.uwb.burst_rate_hz * (1 + 1e-9):
                raise ValueError(f"anchor {a.id}: rate_hz exceeds uwb.burst_rate_hz")
        check_bounds(self.model_dump())  # physical ranges of every field (physynth.bounds)
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


def _dotted(loc: tuple) -> str:
    return ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in loc).replace(".[", "[")


def _format_validation_error(err: ValidationError, source: str) -> str:
    errors = err.errors()
    e = errors[0]
    if e["type"] == "missing":  # a misspelled required key: name the unknown key beside the missing one
        typo = next((x for x in errors if x["type"] == "extra_forbidden" and x["loc"][:-1] == e["loc"][:-1]), None)
        if typo is not None:
            more = f" [+{len(errors) - 2} more]" if len(errors) > 2 else ""
            return (f"scenario {source}: field {_dotted(e['loc'])} is required and {_dotted(typo['loc'])} is not a "
                    f"known field (misspelled?){more}")
    loc = _dotted(e["loc"])
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


def scenario_to_dict(scn: Scenario) -> dict[str, Any]:
    return scn.model_dump(mode="json", exclude_defaults=False)
