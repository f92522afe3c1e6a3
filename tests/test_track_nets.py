"""Learned trackers, torch datasets and the residual GAN (tiny sizes, fixed seeds)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from track_helpers import site_scenario  # noqa: E402

from physynth.errors import PhySynthError  # noqa: E402
from physynth.generate import generate_trace  # noqa: E402
from physynth.models.variation import SiteVariationParams, draw_site  # noqa: E402
from physynth.track.gan import GanConfig, ResidualGan, augment_trace, range_residuals  # noqa: E402
from physynth.track.inputs import track_input  # noqa: E402
from physynth.track.synth import synthetic_trace  # noqa: E402
from physynth.track.torch_data import SyntheticWindows, TraceWindows, WindowSpec, collate_windows  # noqa: E402
from physynth.track.trackers import make_tracker  # noqa: E402
from physynth.track.trackers.nets import NetTracker  # noqa: E402

SMALL = {"hidden": 16, "heads": 2, "window_steps": 12, "stride_steps": 4, "burn_in_steps": 2, "batch_size": 8,
         "decimation": 10, "seed": 0}


@pytest.fixture(scope="module")
def inputs():
    torch.set_num_threads(1)
    scn = site_scenario(noise_m=0.05)
    return [track_input(generate_trace(scn, i, 21)) for i in range(2)]


@pytest.mark.parametrize("arch", ["aoi-fusion", "bilstm"])
def test_network_loss_falls_on_a_small_task(inputs, arch):
    net = make_tracker(arch, epochs=12, lr=3e-3, **SMALL)
    net.fit(inputs)
    loss = net.history[0]["loss"]
    assert loss[-1] < 0.3 * loss[0], loss
    est = net.predict(inputs[0])
    assert est.shape == (inputs[0].n_steps, 3)
    assert np.isfinite(est[inputs[0].eval_mask()]).all()


def test_cosine_schedule_ends_each_stage_on_small_steps(inputs):
    const = make_tracker("aoi-fusion", epochs=3, lr=3e-3, **SMALL).fit(inputs)
    cos = make_tracker("aoi-fusion", epochs=3, lr=3e-3, lr_schedule="cosine", **SMALL).fit(inputs)
    assert const.history[0]["final_lr"] == 3e-3
    assert cos.history[0]["final_lr"] < 1e-6 and cos.history[0]["lr_schedule"] == "cosine"
    assert cos.history[0]["loss"][-1] != const.history[0]["loss"][-1]  # the rate changed the steps
    with pytest.raises(PhySynthError, match="lr_schedule must be constant or cosine"):
        make_tracker("aoi-fusion", lr_schedule="step", **SMALL)


def test_weight_averaging_ends_each_stage_on_the_mean_of_its_second_half(inputs):
    snaps = []
    net = make_tracker("aoi-fusion", epochs=5, lr=3e-3, weight_average="swa", **SMALL)
    net.fit(inputs, progress=lambda msg: snaps.append({k: v.clone() for k, v in net.model.state_dict().items()}))
    assert len(snaps) == 5 and net.history[0]["averaged_epochs"] == 3  # epochs 3, 4 and 5 of 5
    final = net.model.state_dict()
    for k, v in final.items():
        torch.testing.assert_close(v, torch.stack([s[k] for s in snaps[2:]]).mean(dim=0))
    assert any(not torch.equal(final[k], snaps[-1][k]) for k in final)  # not simply the last epoch's weights
    plain = make_tracker("aoi-fusion", epochs=5, lr=3e-3, **SMALL).fit(inputs)
    assert plain.history[0]["loss"] == net.history[0]["loss"]  # averaging leaves the training steps alone
    assert plain.history[0]["averaged_epochs"] == 0
    with pytest.raises(PhySynthError, match="weight_average must be none or swa"):
        make_tracker("aoi-fusion", weight_average="ema", **SMALL)


def test_ekf_prior_is_the_filters_position_and_a_residual_net_corrects_it(inputs):
    from physynth.track.trackers.ekf import EkfTracker

    inp = inputs[0]
    plain, prior = WindowSpec().arrays(inp), WindowSpec(ekf_prior=True).arrays(inp)
    assert plain.g.shape[1] == 12 and prior.g.shape[1] == 15
    np.testing.assert_array_equal(prior.g[:, :12], plain.g)  # appended, nothing else moved
    ekf = EkfTracker(use_imu=False, fit_range_std=False, max_coast_s=1.0).predict_rel(inp)[prior.step]
    fixed = np.isfinite(ekf).all(axis=1)
    assert fixed.mean() > 0.9
    np.testing.assert_allclose(prior.g[fixed, 12:] * 10.0, ekf[fixed], atol=1e-4, rtol=1e-5)
    # residual: with the output layer zeroed the network returns the filter's position itself
    net = make_tracker("aoi-fusion", epochs=1, ekf_prior="residual", **SMALL).fit(inputs)
    with torch.no_grad():
        net.model.head[-1].weight.zero_()
        net.model.head[-1].bias.zero_()
    est = net.predict(inp)[prior.step]
    ok = fixed & np.isfinite(est).all(axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(est[ok], ekf[ok] + inp.ref_enu_m, atol=1e-3)
    # input: one more per-step input; trains, and the state round-trips with it
    net = make_tracker("aoi-fusion", epochs=2, lr=3e-3, ekf_prior="input", **SMALL).fit(inputs)
    assert net.model.fuse[0].in_features == 2 * 16 + 8 + 15
    np.testing.assert_array_equal(NetTracker.from_state(net.state()).predict(inp), net.predict(inp))
    with pytest.raises(PhySynthError, match="ekf_prior must be one of none, input, residual"):
        make_tracker("aoi-fusion", ekf_prior="kalman", **SMALL)


def test_aoi_fusion_takes_any_anchor_count(inputs):
    net = make_tracker("aoi-fusion", epochs=1, **SMALL).fit(inputs)
    three = site_scenario(anchors=[{"id": "A1", "pos_enu_m": [0, -8, 2]}, {"id": "A2", "pos_enu_m": [40, -8, 0.5]},
                                   {"id": "A3", "pos_enu_m": [20, 9, 2.5]}])
    est = net.predict(track_input(generate_trace(three, 0, 1)))
    assert np.isfinite(est[-1]).all()
    mixed = TraceWindows([inputs[0], track_input(generate_trace(three, 0, 1))], net.window_spec())
    batch = collate_windows([mixed[0], mixed[len(mixed) - 1]])
    assert batch["x"].shape[2] == 4 and batch["anchor_ok"].sum().item() == 7


def test_training_is_deterministic_and_state_round_trips(inputs):
    a = make_tracker("aoi-fusion", epochs=2, **SMALL).fit(inputs)
    b = make_tracker("aoi-fusion", epochs=2, **SMALL).fit(inputs)
    assert a.history[0]["loss"] == b.history[0]["loss"]
    c = NetTracker.from_state(a.state())
    np.testing.assert_array_equal(a.predict(inputs[1]), c.predict(inputs[1]))
    old = a.state()  # a state of a release whose fusion layer took 6 per-step features, not 12
    weights = dict(old["weights"])
    weights["fuse.0.weight"] = weights["fuse.0.weight"][:, :-6]
    with pytest.raises(PhySynthError, match="does not fit this release"):
        NetTracker.from_state({**old, "weights": weights})


def test_net_config_holds_its_window_and_takes_the_window_settings_by_name():
    """NetConfig keeps the windows in a WindowSpec; its settings name the window's fields as before
    (``window_steps``, ``route_frame``, ...), and a saved state's flat config reads back."""
    from physynth.track.trackers.nets import NET_SETTINGS, WINDOW_SETTINGS, NetConfig

    cfg = NetConfig.from_settings(window_steps=12, stride_steps=4, decimation=5, use_imu=True, route_frame=True,
                                  ekf_prior="residual", hidden=16, heads=2, burn_in_steps=2)
    assert cfg.window == WindowSpec(length=12, stride=4, decimation=5, use_imu=True, route_frame=True,
                                    ekf_prior=True)  # the windows carry the prior the network uses
    assert NetTracker(config=cfg).window_spec() is cfg.window
    d = cfg.to_dict()
    assert d["window"]["length"] == 12 and NetConfig(**d) == cfg and NetConfig.from_settings(**d) == cfg
    flat = {k: v for k, v in d.items() if k != "window"} | {k: d["window"][f] for k, f in WINDOW_SETTINGS.items()}
    assert set(flat) == NET_SETTINGS and NetConfig.from_settings(**flat) == cfg  # a state saved before the window
    assert cfg.with_settings(ekf_prior="none").window.ekf_prior is False
    assert NetTracker(config=cfg, window_steps=16).config.window.length == 16
    assert set(WINDOW_SETTINGS.values()) <= set(WindowSpec.__dataclass_fields__)
    with pytest.raises(PhySynthError, match="burn_in_steps must be smaller than window_steps"):
        NetConfig.from_settings(window_steps=2, burn_in_steps=2)
    with pytest.raises(PhySynthError, match="invalid WindowSpec"):
        NetConfig.from_settings(stride_steps=0)
    with pytest.raises(PhySynthError, match="exclude each other"):
        NetConfig.from_settings(route_frame=True, random_isometry=True)


def _all_items(ds, workers):
    loader = torch.utils.data.DataLoader(ds, batch_size=5, shuffle=False, num_workers=workers,
                                         collate_fn=collate_windows)
    return [b for b in loader]


def test_on_the_fly_windows_identical_across_workers_and_epochs():
    scn = site_scenario(noise_m=0.1, **{"channel.nlos_prob": 0.1, "availability.dropout_prob": 0.1})
    var = SiteVariationParams(layout_jitter_m=0.5, path_yaw_std_rad=0.1, path_shift_std_m=0.5, path_lateral_std_m=0.5,
                         shuffle_anchors=True)
    spec = WindowSpec(length=8, stride=4, decimation=10)
    ds = SyntheticWindows(scn, 3, 1234, spec, windows_per_trace=4, variation=var, cache_size=1)
    one = _all_items(ds, 0)
    two = _all_items(SyntheticWindows(scn, 3, 1234, spec, windows_per_trace=4, variation=var), 2)
    again = _all_items(ds, 0)
    assert len(one) == len(two) == 3
    for b1, b2, b3 in zip(one, two, again, strict=True):
        for key in b1:
            assert torch.equal(b1[key], b2[key]) and torch.equal(b1[key], b3[key]), key
    other = SyntheticWindows(scn, 3, 1235, spec, windows_per_trace=4, variation=var)[0]
    assert not torch.equal(other["x"], one[0]["x"][0])


def test_variation_moves_layout_and_path_but_not_the_seeded_rest():
    scn = site_scenario()
    plain = synthetic_trace(scn, 0, 5)
    varied = synthetic_trace(scn, 0, 5, SiteVariationParams(layout_jitter_m=0.5, path_shift_std_m=1.0))
    assert not np.allclose(plain.anchors.pos_enu_m, varied.anchors.pos_enu_m)
    assert not np.allclose(plain.truth.pos_enu_m[:10], varied.truth.pos_enu_m[:10])
    np.testing.assert_array_equal(synthetic_trace(scn, 0, 5, SiteVariationParams()).uwb.range_m,
                                  synthetic_trace(scn, 0, 5, SiteVariationParams()).uwb.range_m)


def test_random_routes_stay_on_the_site_and_leave_other_draws_alone():
    from physynth.track.synth import random_route

    rng = np.random.default_rng(3)
    centre = np.array([10.0, -5.0, 1.0])
    for _ in range(200):
        w = np.asarray(random_route(centre, 40.0, 1.2, 8, rng))
        assert w.shape == (8, 3) and np.all(w[:, 2] == 1.2)
        assert np.linalg.norm(w[0, :2] - centre[:2]) <= 3.0 * np.sqrt(2) + 1e-9
        # a leg that would leave the disc turns back: at most one leg (<= 0.5 reach) beyond it
        assert np.max(np.linalg.norm(w[:, :2] - centre[:2], axis=1)) <= 40.0 + 0.5 * 40.0 + 1e-9
        assert np.all(np.linalg.norm(np.diff(w[:, :2], axis=0), axis=1) >= 0.2 * 40.0 - 1e-9)
    scn = site_scenario()
    n = 400
    base, path = np.array([a.pos_enu_m for a in scn.anchors]), scn.path.model_dump(mode="python")

    def site(v, seed):
        return draw_site(v, base, path, lambda: np.asarray(path["waypoints_enu_m"], float), np.random.default_rng(seed))

    routed = [site(SiteVariationParams(random_route_prob=0.5), i)[1] != site(SiteVariationParams(), i)[1]
              for i in range(n)]
    share = np.mean(routed)
    assert abs(share - 0.5) < 5 * np.sqrt(0.25 / n)  # 5 standard errors of a fair coin
    # the other draws come first: without random routes the scenario is the same as before
    a = site(SiteVariationParams(), 9)
    b = site(SiteVariationParams(random_route_prob=1e-12), 9)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]
    tr = synthetic_trace(scn, 0, 5, SiteVariationParams(random_route_prob=1.0))
    assert tr.duration_s > 10 and np.isfinite(tr.uwb.range_m).sum() > 100
    with pytest.raises(ValueError, match="random_route_prob"):
        SiteVariationParams(random_route_prob=1.5)


def test_gan_learns_the_residual_scale_and_augments_only_ranges():
    torch.set_num_threads(1)
    scn = site_scenario(noise_m=0.2, **{"channel.los_mean_m": 0.3})
    traces = [generate_trace(scn, i, 8) for i in range(2)]
    gan = ResidualGan(GanConfig(steps=600, seed=0)).fit(traces, 0.0)
    geo = np.full(4000, 20.0)
    s = gan.sample(geo, seed=1)
    np.testing.assert_array_equal(s, gan.sample(geo, seed=1))
    assert 0.1 < np.median(s) < 0.5 and 0.08 < np.std(s) < 0.4
    aug = augment_trace(traces[0], gan, 0.0, seed=2)
    np.testing.assert_array_equal(aug.uwb.t_s, traces[0].uwb.t_s)
    assert np.array_equal(np.isfinite(aug.uwb.range_m), np.isfinite(traces[0].uwb.range_m))
    _, _, res = range_residuals(aug, 0.0)
    assert 0.1 < np.median(res) < 0.5
