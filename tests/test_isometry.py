"""Turned and mirrored worlds: whole traces (physynth.transform) and network windows (IsometryWindows)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import simple_scenario
from scipy import stats
from track_helpers import site_scenario

from physynth.errors import PhySynthError
from physynth.generate import generate_trace
from physynth.transform import apply_isometry, turn_trace


def _trace(**updates):
    return generate_trace(simple_scenario(**updates), 0, 5)


def _true_ranges(trace):
    p = trace.truth.position_at(trace.uwb.t_s)
    return np.linalg.norm(p - trace.anchors.pos_enu_m[trace.uwb.anchor], axis=1)


SMALL_NET = {"hidden": 16, "heads": 2, "window_steps": 12, "stride_steps": 4, "burn_in_steps": 2, "batch_size": 8,
             "decimation": 10, "seed": 0, "lr": 3e-3}


def _site_runs(n_train: int):
    """Tiny-network set-up of the learned-tracker tests: ``n_train`` training inputs and one test trace."""
    torch = pytest.importorskip("torch")
    from physynth.track.inputs import track_input

    torch.set_num_threads(1)
    scn = site_scenario(noise_m=0.05)
    return [track_input(generate_trace(scn, i, 21)) for i in range(n_train)], generate_trace(scn, 9, 21)


@pytest.mark.parametrize("mirror", [False, True])
def test_turning_keeps_every_distance_and_moves_positions_and_acceleration(mirror):
    tr = _trace(imu={"rate_hz": 100.0, "white_noise_density_mps2_per_sqrt_hz": [0.0, 0.0, 0.0]})
    turned = turn_trace(tr, 1.1, mirror=mirror)
    np.testing.assert_allclose(_true_ranges(turned), _true_ranges(tr), atol=1e-9)
    np.testing.assert_array_equal(turned.uwb.range_m, tr.uwb.range_m)
    centre = tr.anchors.pos_enu_m.mean(axis=0)
    np.testing.assert_allclose(turned.anchors.pos_enu_m.mean(axis=0), centre, atol=1e-9)
    # heights, speeds and the size of the acceleration are those of the original run
    np.testing.assert_allclose(turned.truth.pos_enu_m[:, 2], tr.truth.pos_enu_m[:, 2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(turned.truth.vel_enu_mps, axis=1),
                               np.linalg.norm(tr.truth.vel_enu_mps, axis=1), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(turned.imu.acc_mps2, axis=1), np.linalg.norm(tr.imu.acc_mps2, axis=1),
                               atol=1e-9)
    # the direction of travel has turned: 1.1 rad counter-clockwise (clockwise after a mirror)
    d0 = tr.truth.pos_enu_m[-1, :2] - tr.truth.pos_enu_m[0, :2]
    d1 = turned.truth.pos_enu_m[-1, :2] - turned.truth.pos_enu_m[0, :2]
    sign = -1.0 if mirror else 1.0
    turn = np.arctan2(d1[1], d1[0]) - sign * np.arctan2(d0[1], d0[0])
    assert abs(np.angle(np.exp(1j * turn)) - 1.1) < 1e-9
    # estimates made in the original frame move with the recorded isometry
    np.testing.assert_allclose(apply_isometry(turned.meta, tr.truth.pos_enu_m), turned.truth.pos_enu_m, atol=1e-9)
    np.testing.assert_array_equal(apply_isometry(tr.meta, tr.truth.pos_enu_m), tr.truth.pos_enu_m)


def test_two_turns_compose_into_one():
    tr = _trace()
    twice = turn_trace(turn_trace(tr, 0.4), 0.9)
    once = turn_trace(tr, 1.3)
    np.testing.assert_allclose(twice.truth.pos_enu_m, once.truth.pos_enu_m, atol=1e-9)
    np.testing.assert_allclose(np.asarray(twice.meta["isometry"]["matrix"]),
                               np.asarray(once.meta["isometry"]["matrix"]), atol=1e-12)
    np.testing.assert_allclose(apply_isometry(twice.meta, tr.anchors.pos_enu_m), twice.anchors.pos_enu_m, atol=1e-9)


def test_attitude_turns_with_the_world():
    from scipy.spatial.transform import Rotation

    tr = _trace(attitude={"kind": "tangent"}, imu_frames=["enu-gravity-free", "body-flu"])
    turned = turn_trace(tr, 0.7)
    # body x stays along the velocity: the attitude turned by the same angle as the path
    fwd = Rotation.from_quat(turned.truth.quat_wxyz, scalar_first=True).apply([1.0, 0.0, 0.0])
    v = turned.truth.vel_enu_mps
    moving = np.linalg.norm(v, axis=1) > 0.5
    cos = np.sum(fwd[moving] * v[moving], axis=1) / np.linalg.norm(v[moving], axis=1)
    assert cos.min() > 0.99
    np.testing.assert_array_equal(turned.imu.acc_body_mps2, tr.imu.acc_body_mps2)
    with pytest.raises(ValueError, match="finite"):
        turn_trace(tr, float("nan"))
    with pytest.raises(ValueError, match="centre_enu_m"):
        turn_trace(tr, 0.1, centre_enu_m=[0.0, 1.0])


@pytest.mark.parametrize("mirror", [False, True])
def test_a_mirrored_tumbling_body_stays_right_handed_and_consistent(mirror):
    from scipy.spatial.transform import Rotation

    tr = _trace(attitude={"kind": "tumble", "tumble_rate_std_radps": 1.0},
                imu_frames=["enu-gravity-free", "body-flu"])
    out = turn_trace(tr, 2.0, mirror=mirror)
    rot = Rotation.from_quat(out.truth.quat_wxyz, scalar_first=True)
    assert np.all(np.linalg.det(rot.as_matrix()) > 0.999)
    # the attitude integrates the stated body rate (row k: the rate over [t_k, t_k+1))
    dt = np.diff(out.truth.t_s)
    rate = (rot[:-1].inv() * rot[1:]).as_rotvec() / dt[:, None]
    np.testing.assert_allclose(rate, out.truth.omega_body_radps[:-1], atol=1e-6)
    # the body-frame specific force read in ENU is that of the moved world: R' f' = M R f
    m = np.asarray(out.meta["isometry"]["matrix"])
    r_old = Rotation.from_quat(tr.truth.quat_wxyz, scalar_first=True)
    k = np.searchsorted(tr.truth.t_s, tr.imu.t_s[:50])
    np.testing.assert_allclose(rot[k].apply(out.imu.acc_body_mps2[:50]),
                               r_old[k].apply(tr.imu.acc_body_mps2[:50]) @ m.T, atol=1e-9)


def test_a_turned_window_is_the_window_of_the_turned_trace():
    pytest.importorskip("torch")
    from physynth.track.features import network_arrays
    from physynth.track.inputs import track_input
    from physynth.track.torch_data import turn_window, window_item
    from physynth.transform import isometry_matrix

    tr = _trace(imu={"rate_hz": 100.0})
    for yaw, mirror in ((0.8, False), (2.5, True)):
        turned = turn_trace(tr, yaw, mirror=mirror)
        a = network_arrays(track_input(tr))
        b = network_arrays(track_input(turned))
        mine = turn_window(window_item(a, 3, 16), isometry_matrix(yaw, mirror))
        theirs = window_item(b, 3, 16)
        for key in ("x", "g", "acc", "y"):
            np.testing.assert_allclose(mine[key].numpy(), theirs[key].numpy(), atol=2e-4, err_msg=key)
        assert not np.allclose(mine["y"].numpy(), window_item(a, 3, 16)["y"].numpy(), atol=1e-2)


def test_isometry_windows_draw_uniform_angles_and_fair_mirrors_deterministically():
    pytest.importorskip("torch")
    from physynth.track.torch_data import IsometryWindows

    n = 2000
    iso = IsometryWindows(range(n), seed=3)
    mats = np.array([iso.matrix(j) for j in range(n)])
    mirrored = np.linalg.det(mats) < 0
    # tolerance: 5 standard errors of a fair coin over n draws
    assert abs(mirrored.mean() - 0.5) < 5 * np.sqrt(0.25 / n)
    # the image of the x axis; a mirror y -> -y leaves it in place, so its angle is the turn
    yaw = np.arctan2(mats[:, 1, 0], mats[:, 0, 0]) % (2 * np.pi)
    assert stats.kstest(yaw / (2 * np.pi), "uniform").pvalue > 1e-3
    np.testing.assert_array_equal(IsometryWindows(range(n), seed=3).matrix(17), iso.matrix(17))
    assert not np.allclose(IsometryWindows(range(n), seed=4).matrix(17), iso.matrix(17))
    no_mirror = IsometryWindows(range(n), seed=3, mirror_prob=0.0)
    assert all(np.linalg.det(no_mirror.matrix(j)) > 0 for j in range(200))
    with pytest.raises(ValueError, match="mirror_prob"):
        IsometryWindows(range(3), seed=0, mirror_prob=1.5)


def test_a_network_trained_on_turned_windows_tracks_a_run_in_another_direction():
    """The site's walks all head east. Without turned windows a small network learns that heading and is
    lost on the same walk heading north or west; with them it tracks every direction alike."""
    train, test = _site_runs(4)
    from physynth.track.inputs import track_input
    from physynth.track.trackers import make_tracker

    small = {**SMALL_NET, "epochs": 12}

    def rmse(net, yaw):
        inp = track_input(turn_trace(test, yaw))
        err = net.predict(inp) - inp.pos_enu_m
        return float(np.sqrt(np.mean(np.sum(err[inp.eval_mask()] ** 2, axis=1))))

    plain = make_tracker("aoi-fusion", **small).fit(train)
    turned = make_tracker("aoi-fusion", random_isometry=True, **small).fit(train)
    assert turned.history[0]["random_isometry"] and not plain.history[0]["random_isometry"]
    plain_err = [rmse(plain, y) for y in (0.0, np.pi / 2, np.pi)]
    turned_err = [rmse(turned, y) for y in (0.0, np.pi / 2, np.pi)]
    assert min(plain_err[1:]) > 4 * plain_err[0], plain_err
    assert max(turned_err) < 1.5 * min(turned_err), turned_err
    assert max(turned_err) < 0.5 * min(plain_err[1:]), (plain_err, turned_err)


def test_test_time_isometries_make_predictions_exactly_equivariant():
    """With the 8 test-time isometries (turns by multiples of 90 deg and their mirrors), a run turned by
    90 deg or mirrored is predicted as the turned prediction of the original run; with 1, it is not."""
    torch = pytest.importorskip("torch")
    from physynth.track.inputs import track_input
    from physynth.track.trackers import make_tracker
    from physynth.transform import isometry_matrix

    torch.set_num_threads(1)
    small = {"hidden": 16, "heads": 2, "window_steps": 12, "stride_steps": 4, "burn_in_steps": 2, "batch_size": 8,
             "decimation": 10, "seed": 0, "epochs": 2, "lr": 3e-3, "random_isometry": True}
    scn = site_scenario(noise_m=0.05)
    train = [track_input(generate_trace(scn, i, 21)) for i in range(2)]
    test = generate_trace(scn, 9, 21)
    net = make_tracker("aoi-fusion", **small).fit(train)
    base = track_input(test)
    centre = base.ref_enu_m
    for yaw, mirror in ((np.pi / 2, False), (0.0, True), (np.pi, True)):
        m = isometry_matrix(yaw, mirror)
        moved = track_input(turn_trace(test, yaw, mirror=mirror))
        expect = (net.predict(base) - centre) @ m.T + centre
        np.testing.assert_allclose(net.predict(moved), expect, atol=2e-4)
    net.config = net.config.__class__(**{**net.config.to_dict(), "test_isometries": 1})
    moved = track_input(turn_trace(test, np.pi / 2))
    expect = (net.predict(base) - centre) @ isometry_matrix(np.pi / 2).T + centre
    assert np.nanmax(np.abs(net.predict(moved) - expect)) > 1e-2
    with pytest.raises(PhySynthError, match="test_isometries"):
        make_tracker("aoi-fusion", test_isometries=3)


# ---------------------------------------------------------------- the route frame
def test_route_heading_turns_with_the_run_and_route_frame_undoes_any_turn():
    from physynth.track.features import network_arrays, route_frame, route_heading_rad, turn_arrays
    from physynth.track.inputs import track_input
    from physynth.transform import isometry_matrix

    tr = generate_trace(site_scenario(noise_m=0.05), 3, 21)
    arr = network_arrays(track_input(tr))
    h0 = route_heading_rad(arr)
    canon, m0 = route_frame(arr)
    assert abs(route_heading_rad(canon)) < 1e-5  # the frame's route heads east
    np.testing.assert_allclose(m0, isometry_matrix(-h0), atol=1e-12)
    for yaw in (0.7, 2.0, -2.9):
        turned = network_arrays(track_input(turn_trace(tr, yaw)))
        assert abs(np.angle(np.exp(1j * (route_heading_rad(turned) - h0 - yaw)))) < 1e-4
        other, _ = route_frame(turned)
        for key in ("x", "g", "acc", "y"):  # the same inputs whatever the run's compass heading
            np.testing.assert_allclose(getattr(other, key), getattr(canon, key), atol=3e-4, err_msg=key)
    # turning arrays is turning the trace (numpy twin of turn_window)
    moved = turn_arrays(arr, isometry_matrix(0.7))
    direct = network_arrays(track_input(turn_trace(tr, 0.7)))
    np.testing.assert_allclose(moved.y, direct.y, atol=2e-4)
    np.testing.assert_allclose(moved.g, direct.g, atol=2e-4)


def test_a_route_frame_network_predicts_any_turned_run_as_the_turned_prediction():
    """Training and prediction in each run's route frame: the prediction of a turned run is the turned
    prediction of the run (to float32 precision), with no test-time copies; without the frame it is not."""
    train, test = _site_runs(2)
    from physynth.track.inputs import track_input
    from physynth.track.trackers import make_tracker
    from physynth.transform import isometry_matrix

    small = {**SMALL_NET, "epochs": 2}
    base = track_input(test)
    centre = base.ref_enu_m
    nets = {frame: make_tracker("aoi-fusion", route_frame=frame, **small).fit(train) for frame in (True, False)}
    assert nets[True].history[0]["route_frame"] and not nets[False].history[0]["route_frame"]
    for yaw in (np.pi / 3, -2.2):
        moved = track_input(turn_trace(test, yaw))
        for frame, net in nets.items():
            expect = (net.predict(base) - centre) @ isometry_matrix(yaw).T + centre
            gap = np.nanmax(np.abs(net.predict(moved) - expect))
            assert (gap < 1e-4) if frame else (gap > 1.0), (frame, yaw, gap)
    with pytest.raises(PhySynthError, match="route_frame"):
        make_tracker("aoi-fusion", route_frame=True, random_isometry=True)
