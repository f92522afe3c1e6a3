"""The generator: a scenario composed through path -> motion -> IMU -> UWB -> availability -> Trace.

Each model sees only its own parameters; this module hands each one its slice of the scenario.

Trace ``i`` draws every component from its own stream ``SeedSequence(root, spawn_key=(i, component))``
(:mod:`physynth.rng`), so it is the same whether 5 or 500 traces are generated, in any order.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from . import __version__
from ._alloc import tune_allocator
from ._args import check_int, check_seed
from .bounds import check_trip, trip_range_s
from .constants import IMU_BODY_FRAME, IMU_FRAME
from .errors import ScenarioError
from .models.attitude import simulate_attitude
from .models.availability import AvailabilityArrays, availability_arrays, simulate_availability
from .models.imu import simulate_body_imu, simulate_imu
from .models.jitter import add_jitter
from .models.motion import SpeedShape, compile_speed_shape, draw_run, kinematics
from .models.path import PathGeometry, PathParams, compile_path, draw_perturbation
from .models.uwb import ChannelArrays, channel_arrays, late_stamps, simulate_uwb, uwb_record
from .models.variation import draw_site, layout_anchors, nlos_scaled
from .records import Anchors, Imu, Trace, Truth, Uwb
from .rng import component_rng, new_root_seed
from .scenario import Scenario, scenario_to_dict


@dataclass(frozen=True, slots=True)
class CompiledScenario:
    """A scenario with its geometry, speed shape and channel tables built once for many traces."""

    scenario: Scenario
    geometry: PathGeometry
    shape: SpeedShape
    channel: ChannelArrays | None  # None without anchors (an IMU-only scenario)
    availability: AvailabilityArrays | None
    anchors: Anchors
    lateral_dir: np.ndarray


def compile_scenario(scn: Scenario) -> CompiledScenario:
    """The scenario's per-scenario tables, built once for many traces.

    The first call in a process also tunes glibc's allocator (:mod:`physynth._alloc`; opt-out
    ``PHYSYNTH_MALLOPT=0``): fewer page faults per trace, the same values.

    Raises
    ------
    ScenarioError
        ``scn`` is not a :class:`Scenario`, or its shortest trip gives fewer truth samples than a trace
        needs (:func:`physynth.bounds.check_trip`, as :func:`physynth.workflows.generate_dataset` checks).
    """
    if not isinstance(scn, Scenario):
        raise ScenarioError(f"expected a Scenario, got {type(scn).__name__} (physynth.load_scenario reads a preset "
                            "name, a scenario file or a mapping)")
    geometry, shape = compile_path(scn.path), compile_speed_shape(scn.motion.profile)
    check_trip(scn, min_trip_s=trip_range_s(scn, geometry.length_m, shape.mean)[0])
    tune_allocator()
    return CompiledScenario(
        scenario=scn,
        geometry=geometry,
        shape=shape,
        channel=(channel_arrays(scn.uwb, scn.anchors, [scn.channel_for(a) for a in scn.anchor_ids])
                 if scn.anchors else None),
        availability=(availability_arrays(scn.availability, [scn.availability_for(a) for a in scn.anchor_ids])
                      if scn.anchors else None),
        anchors=Anchors(ids=scn.anchor_ids, names=tuple(a.name or a.id for a in scn.anchors),
                        pos_enu_m=np.array([a.pos_enu_m for a in scn.anchors], dtype=float).reshape(-1, 3)),
        lateral_dir=geometry.lateral_direction(),
    )


def _compiled(scn: Scenario | CompiledScenario) -> CompiledScenario:
    return scn if isinstance(scn, CompiledScenario) else compile_scenario(scn)


def vary_site(cs: CompiledScenario, index: int, root_seed: int) -> tuple[CompiledScenario, dict]:
    """The compiled scenario of trace ``index`` with its own anchor layout and path (the scenario's
    ``variation``, :func:`physynth.models.variation.draw_site`), and the record of the draw.

    Only what the site changes is rebuilt: the path's geometry and the anchor positions (the channel's
    tables do not depend on them); a drawn layout (``variation.layout_distribution``) brings anchors of its
    own (:func:`physynth.models.variation.layout_anchors`: new ids, each with a pool anchor's channel and
    availability), whose channel and availability tables are built anew. The scenario is updated without a
    second validation (the draws are positions and spreads of the validated section, the channels and
    availabilities those of its anchors).
    """
    s = cs.scenario
    geo = cs.geometry

    def path_points() -> np.ndarray:
        return np.asarray(geo.evaluate(np.linspace(0.0, geo.length_m, 200))[0], dtype=float)

    pos, path, record = draw_site(s.variation, cs.anchors.pos_enu_m, s.path.model_dump(mode="python"), path_points,
                                  component_rng(root_seed, index, "site"))
    path_p = PathParams.model_validate(path)
    geometry = compile_path(path_p)
    if "layout_drawn" in record:  # a whole layout of its own: new anchors, their tables rebuilt
        varied = s.model_copy(update={"path": path_p, "variation": None,
                                      **layout_anchors(s, pos, record["layout_drawn"])})
        channel = channel_arrays(varied.uwb, varied.anchors, [varied.channel_for(a) for a in varied.anchor_ids])
        availability = availability_arrays(varied.availability,
                                           [varied.availability_for(a) for a in varied.anchor_ids])
        anchors = Anchors(ids=varied.anchor_ids, names=varied.anchor_ids, pos_enu_m=pos)
    else:
        anchors_p = [a.model_copy(update={"pos_enu_m": [float(x) for x in p]}) for a, p in zip(s.anchors, pos,
                                                                                                strict=True)]
        varied = s.model_copy(update={"path": path_p, "anchors": anchors_p, "variation": None})
        channel = None if cs.channel is None else replace(cs.channel, anchor_pos_enu_m=pos)
        availability = cs.availability
        anchors = Anchors(ids=cs.anchors.ids, names=cs.anchors.names, pos_enu_m=pos)
    if "nlos_scale" in record and channel is not None:  # this trace's own NLOS frequency: tables rebuilt
        varied = varied.model_copy(update=nlos_scaled(varied, record["nlos_scale"]))
        channel = channel_arrays(varied.uwb, varied.anchors, [varied.channel_for(a) for a in varied.anchor_ids])
    return replace(cs, scenario=varied, geometry=geometry, lateral_dir=geometry.lateral_direction(),
                   channel=channel, availability=availability, anchors=anchors), record


def generate_trace(scn: Scenario | CompiledScenario, index: int, root_seed: int) -> Trace:
    """Trace ``index`` of the dataset with root seed ``root_seed``.

    Raises
    ------
    ArgumentError
        ``index`` or ``root_seed`` is not a non-negative integer (a float is never truncated).
    ScenarioError
        As :func:`compile_scenario`.
    """
    index = check_int(index, "index", what="the index of the trace")
    root_seed = check_int(root_seed, "root_seed", what="the root seed")
    cs = _compiled(scn)
    site = None
    if cs.scenario.variation is not None:  # this trace's own anchor layout and path
        cs, site = vary_site(cs, index, root_seed)
    s = cs.scenario
    pert = draw_perturbation(s.path.perturbation, rng=component_rng(root_seed, index, "path"))
    run = draw_run(s.motion, rng=component_rng(root_seed, index, "motion"))
    kin = kinematics(cs.geometry, pert, s.motion, cs.shape, run, rate_hz=s.truth_rate_hz,
                     reverse=s.path.reverse, lateral_dir=cs.lateral_dir)
    att = simulate_attitude(kin.t_s, kin.vel_enu_mps, kin.acc_enu_mps2, s.attitude,
                            rng=component_rng(root_seed, index, "attitude") if s.attitude.kind == "tumble" else None)
    if s.motion.jitter.active:  # the position shakes; the attitude follows the path
        kin = add_jitter(kin, s.motion.jitter, rng=component_rng(root_seed, index, "jitter"))
    imu = _imu(kin, att, s, root_seed, index)
    if cs.channel is None or cs.availability is None:  # no anchors: no ranging attempts
        uwb = Uwb(t_s=np.zeros(0), anchor=np.zeros(0, np.int16), range_m=np.zeros(0))
    else:
        sway = component_rng(root_seed, index, "uwb_sway") if s.uwb.antenna_sway_std_m > 0 else None
        tag = component_rng(root_seed, index, "uwb_tag") if cs.channel.tag_prob > 0 else None
        tries = simulate_uwb(kin, s.uwb, cs.channel, rng=component_rng(root_seed, index, "uwb"), sway_rng=sway,
                             tag_rng=tag, omega_body_radps=att.omega_body_radps)
        outage, dropped = simulate_availability(tries.t_true_s, tries.anchor, tries.burst, tries.bursts_s,
                                                cs.availability, s.uwb.burst_rate_hz, range_m=tries.true_range_m,
                                                rng=component_rng(root_seed, index, "availability"),
                                                rows_of=tries.anchor_rows)
        uwb = uwb_record(tries, outage=outage, dropped=dropped)
        if s.uwb.late_burst_prob > 0:  # stamps delivered late (own stream: nothing else changes)
            uwb = late_stamps(uwb, s.uwb.late_burst_prob, s.uwb.late_burst_delay_s,
                              rng=component_rng(root_seed, index, "uwb_late"), t_max_s=float(kin.t_s[-1]))
    meta = {
        "source": "physynth",
        "root_seed": int(root_seed),
        "spawn_key": [int(index)],
        "speed_factor": run.speed_factor,
        "length_factor": run.length_factor,
        "lateral_offset_m": pert.lateral_m,
        "sag_offset_m": pert.sag_m,
    }
    if site is not None:
        meta["site_variation"] = site  # which layout, the path's turn and shift, a random route or not
    if s.uwb.time_offset_std_s > 0 and cs.channel is not None:
        meta["uwb_time_offset_s"] = tries.time_offset_s  # the trace's own lag (a label)
    truth = Truth(t_s=kin.t_s, pos_enu_m=kin.pos_enu_m, vel_enu_mps=kin.vel_enu_mps, quat_wxyz=att.quat_wxyz,
                  omega_body_radps=att.omega_body_radps)
    return Trace(truth=truth, imu=imu, uwb=uwb, anchors=cs.anchors, meta=meta)


def _imu(kin, att, s: Scenario, root_seed: int, index: int) -> Imu:
    """The IMU record in the scenario's frames: ENU gravity-free (stream ``imu``), body (``imu_body``)."""
    enu = (simulate_imu(kin, s.imu, rng=component_rng(root_seed, index, "imu"), omega_body_radps=att.omega_body_radps,
                        attitude=att.rot if any(s.imu.lever_arm_m) else None)  # rotations only for a lever arm
           if IMU_FRAME in s.imu_frames else None)
    if IMU_BODY_FRAME not in s.imu_frames:
        return enu
    t_b, acc_b, gyro_b = simulate_body_imu(kin.t_s, kin.acc_enu_mps2, att.quat_wxyz, att.omega_body_radps,
                                           s.body_imu, rng=component_rng(root_seed, index, "imu_body"))
    if enu is not None and enu.t_s.shape != t_b.shape:
        raise ValueError("ENU and body IMU time bases differ")  # prevented by the scenario validator
    return Imu(t_s=t_b, acc_mps2=None if enu is None else enu.acc_mps2, acc_body_mps2=acc_b, gyro_body_radps=gyro_b)


def generate_traces(scn: Scenario | CompiledScenario, n: int, seed: int | None = None,
                    start: int = 0) -> Iterator[Trace]:
    """Traces ``start .. start + n - 1`` (lazily; ``n=0`` yields none). ``seed=None`` draws a fresh root seed.

    Raises
    ------
    ArgumentError
        ``n``, ``start`` or ``seed`` is not a non-negative integer (at the call, not at the first trace;
        also a ``ValueError``).
    ScenarioError
        As :func:`compile_scenario` (at the call).
    """
    n = check_int(n, "n", what="the number of traces")
    start = check_int(start, "start", what="the index of the first trace")
    seed = check_seed(seed)
    cs = _compiled(scn)
    root = new_root_seed() if seed is None else seed
    return (generate_trace(cs, i, root) for i in range(start, start + n))


def dataset_meta(scn: Scenario, root_seed: int) -> dict:
    return {
        "kind": "synthetic",
        "scenario": scenario_to_dict(scn),
        "scenario_name": scn.name,
        "root_seed": int(root_seed),
        "seeding": "trace i uses numpy SeedSequence(root_seed, spawn_key=(i, component)), "
                   "components path=0 motion=1 imu=2 uwb=3 availability=4 attitude=5 imu_body=6 jitter=7 uwb_sway=8 "
                   "uwb_tag=9 uwb_late=10 site=100",
        "imu_frame": IMU_FRAME,
        "imu_frames": list(scn.imu_frames),
        "provenance": {"generator": f"physynth {__version__}", "pid": os.getpid()},
    }
