"""The scenario's ``variation`` section: every trace draws its own anchor layout and path."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from physynth.bounds import estimate_size
from physynth.cli import main
from physynth.errors import ScenarioError
from physynth.generate import compile_scenario, generate_trace, generate_traces
from physynth.io.dataset import read_dataset
from physynth.io.scenario_file import load_scenario
from physynth.models.variation import SiteVariationParams, draw_site, recorded_layouts
from physynth.scenario import Scenario, scenario_from_dict, scenario_to_dict
from physynth.studies.subset import subset_scenario
from physynth.track.synth import synthetic_trace

SEED = 11


@pytest.fixture(scope="module")
def base() -> Scenario:
    return load_scenario("cablecar-descending")


def with_variation(scn: Scenario, **kw) -> Scenario:
    d = scenario_to_dict(scn)
    d["variation"] = kw
    return scenario_from_dict(d, "test")


def shifted_layout(scn: Scenario, de: float) -> list[list[float]]:
    return [[a.pos_enu_m[0] + de, a.pos_enu_m[1], a.pos_enu_m[2]] for a in scn.anchors]


@pytest.mark.parametrize("layout_distribution", [None, {"anchor_count": [3, 8], "route_offset_m": [0.0, 3.0]}],
                         ids=["layouts", "layout-distribution"])
def test_section_gives_the_tracking_study_traces_bit_for_bit(base, layout_distribution):
    lay = [shifted_layout(base, 0.0), shifted_layout(base, 3.0)]
    study = SiteVariationParams(layouts=lay, shuffle_anchors=True, random_route_prob=0.5,
                           layout_distribution=layout_distribution)
    scn = with_variation(base, **study.model_dump())
    cs = compile_scenario(scn)
    routes, counts = set(), set()
    for i in range(6):
        a, b = synthetic_trace(base, i, SEED, study), generate_trace(cs, i, SEED)
        routes.add(b.meta["site_variation"]["random_route"])
        counts.add(len(b.anchors))
        assert a.anchors.ids == b.anchors.ids
        assert np.array_equal(a.anchors.pos_enu_m, b.anchors.pos_enu_m)
        assert np.array_equal(a.truth.pos_enu_m, b.truth.pos_enu_m)
        assert np.array_equal(a.uwb.range_m, b.uwb.range_m, equal_nan=True)
        assert np.array_equal(a.imu.acc_mps2, b.imu.acc_mps2)
    assert routes == {True, False}  # both kinds of trace were compared
    assert (len(counts) > 1) == (layout_distribution is not None)  # drawn layouts of several anchor counts


def test_each_trace_has_its_own_site_the_same_in_any_order(base):
    scn = with_variation(base, layout_jitter_m=0.5, path_yaw_std_rad=0.1, path_shift_std_m=2.0)
    first = list(generate_traces(scn, 4, seed=SEED))
    alone = next(generate_traces(scn, 1, seed=SEED, start=2))
    assert np.array_equal(alone.anchors.pos_enu_m, first[2].anchors.pos_enu_m)
    assert np.array_equal(alone.truth.pos_enu_m, first[2].truth.pos_enu_m)
    starts = np.array([t.truth.pos_enu_m[0] for t in first])
    anchors = np.array([t.anchors.pos_enu_m for t in first])
    assert np.all(np.ptp(starts[:, :2], axis=0) > 0.1) and np.all(np.ptp(anchors[:, :, :2], axis=0) > 0.05)
    assert all(set(t.meta["site_variation"]) == {"layout", "yaw_rad", "shift_m", "random_route"} for t in first)
    plain = generate_trace(base, 2, SEED)  # the other components' streams do not move
    assert np.array_equal(plain.anchors.pos_enu_m, np.array([a.pos_enu_m for a in base.anchors]))


def test_path_is_turned_about_the_anchor_centroid_and_shifted(base):
    scn = with_variation(base, layout_jitter_m=0.0, layout_jitter_up_m=0.0, path_yaw_std_rad=0.3,
                         path_shift_std_m=5.0, path_lateral_std_m=0.0, path_sag_std_m=0.0)
    centre = np.mean([a.pos_enu_m for a in base.anchors], axis=0)
    ref = generate_trace(with_variation(base, layout_jitter_m=0.0, layout_jitter_up_m=0.0, path_yaw_std_rad=0.0,
                                        path_shift_std_m=0.0, path_lateral_std_m=0.0, path_sag_std_m=0.0), 0, SEED)
    for i in range(3):
        t = generate_trace(scn, i, SEED)
        rec = t.meta["site_variation"]
        c, s = np.cos(rec["yaw_rad"]), np.sin(rec["yaw_rad"])
        p0 = ref.truth.pos_enu_m[0]
        want = np.array([[c, -s], [s, c]]) @ (p0[:2] - centre[:2]) + centre[:2] + rec["shift_m"]
        assert np.allclose(t.truth.pos_enu_m[0, :2], want, atol=1e-6)
        assert t.truth.pos_enu_m[0, 2] == pytest.approx(p0[2], abs=1e-6)
        assert np.array_equal(t.anchors.pos_enu_m, ref.anchors.pos_enu_m)


def test_draws_have_the_configured_spreads():
    v = SiteVariationParams(layouts=[[[0.0, 0.0, 0.0]] * 3, [[10.0, 0.0, 0.0]] * 3, [[0.0, 10.0, 0.0]] * 3],
                            layout_jitter_m=0.4, layout_jitter_up_m=0.2, path_yaw_std_rad=0.25, path_shift_std_m=3.0)
    path = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [20, 0, 1]], "perturbation": {}}
    n = 600
    rng = np.random.default_rng(5)
    draws = [draw_site(v, np.zeros((3, 3)), path, lambda: np.zeros((2, 3)), rng) for _ in range(n)]
    yaw = np.array([d[2]["yaw_rad"] for d in draws])
    shift = np.array([d[2]["shift_m"] for d in draws])
    k = np.array([d[2]["layout"] for d in draws])
    pos = np.array([d[0] for d in draws])
    base = np.array([v.layouts[j] for j in k])
    jit = pos - base
    tol = 4.0 / np.sqrt(2 * n)  # 4 standard errors of a sample std, relative
    assert np.std(yaw) == pytest.approx(0.25, rel=tol)
    assert np.std(shift) == pytest.approx(3.0, rel=tol / np.sqrt(2))
    assert np.std(jit[:, :, :2]) == pytest.approx(0.4, rel=tol / np.sqrt(6))
    assert np.std(jit[:, :, 2]) == pytest.approx(0.2, rel=tol / np.sqrt(3))
    counts = np.bincount(k, minlength=3)  # uniform choice: each within 4 binomial standard deviations
    assert np.all(np.abs(counts - n / 3) < 4 * np.sqrt(n * (1 / 3) * (2 / 3)))


def test_random_routes_fit_the_size_estimate(base):
    scn = with_variation(base, random_route_prob=1.0, random_route_points=12)
    est = estimate_size(scn, 5)
    assert est.duration_s > estimate_size(base, 5).duration_s  # a route can be longer than the cable
    for t in generate_traces(scn, 5, seed=SEED):
        assert t.meta["site_variation"]["random_route"]
        assert t.duration_s <= est.duration_s


def test_bad_sections_are_one_clear_error(base):
    with pytest.raises(ScenarioError, match=r"variation\.layouts\[0\] holds 2 position"):
        with_variation(base, layouts=[[[0, 0, 0], [1, 1, 1]]])
    with pytest.raises(ScenarioError, match="variation.path_yaw_std_rad"):
        with_variation(base, path_yaw_std_rad=4.0)
    with pytest.raises(ScenarioError, match="layout_jitter_m"):
        with_variation(base, layout_jitter_m=-1.0)


def test_recorded_layouts_and_anchor_subsets(base):
    ids = base.anchor_ids
    prov = {"anchor_layout": {"layouts": {
        "run a": {a: [float(i), 0.0, 1.0] for i, a in enumerate(ids)},
        "run b": {a: [float(i), 5.0, 1.0] for i, a in enumerate(reversed(ids))},
        "run c": {a: [0.0, 0.0, 0.0] for a in ids[:-1]},  # another set of anchors: not a layout of these
    }}}
    lays = recorded_layouts(prov, ids)
    assert len(lays) == 2 and lays[0][1] == [1.0, 0.0, 1.0] and lays[1][0] == [float(len(ids) - 1), 5.0, 1.0]
    assert recorded_layouts({}, ids) == []
    scn = with_variation(base, layouts=lays)
    sub = subset_scenario(scn, [ids[1], ids[3]])
    assert sub.variation.layouts == [[lays[0][1], lays[0][3]], [lays[1][1], lays[1][3]]]


@pytest.mark.parametrize("prov", [{"anchor_layout": "garbage"}, {"anchor_layout": {"layouts": ["a"]}},
                                  {"anchor_layout": {"layouts": {"run": {"A1": [1.0, "x", 2.0]}}}},
                                  {"anchor_layout": {"layouts": {"run": {"A1": [1.0, 2.0]}}}}])
def test_a_malformed_recorded_layout_is_one_clear_error(base, tmp_path, capsys, prov):
    d = scenario_to_dict(base)
    d["provenance"] = prov
    from physynth.io.scenario_file import save_scenario

    path = tmp_path / "site.yaml"
    save_scenario(scenario_from_dict(d, "t"), path)  # provenance is free-form: the file itself loads
    with pytest.raises(SystemExit) as exc:
        main(["generate", "-s", str(path), "-n", "2", "--vary-site", "--out", str(tmp_path / "ds")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "provenance.anchor_layout" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "ds").exists()


def test_generate_vary_site_uses_the_recorded_layouts(base, tmp_path, capsys):
    d = scenario_to_dict(base)
    layouts = {k: dict(zip(base.anchor_ids, shifted_layout(base, de), strict=True))
               for k, de in (("a", 0.0), ("b", 40.0))}
    d["provenance"] = {"anchor_layout": {"layouts": layouts}}
    from physynth.io.scenario_file import save_scenario

    path = tmp_path / "site.yaml"
    save_scenario(scenario_from_dict(d, "t"), path)
    with pytest.raises(SystemExit) as exc:
        main(["generate", "-s", str(path), "-n", "6", "--seed", "3", "--vary-site", "--out", str(tmp_path / "ds")])
        raise SystemExit(0)
    assert (exc.value.code or 0) == 0
    out = capsys.readouterr().out
    assert "site varied per trace around 2 anchor layouts (--vary-site defaults; the" in out  # not the (absent)
    assert "layouts the calibration recorded)" in out and max(map(len, out.splitlines()[1:])) <= 80  # section
    ds = read_dataset(tmp_path / "ds")
    east = np.array([t.anchors.pos_enu_m[:, 0].mean() for t in ds.traces])
    east0 = np.mean([a.pos_enu_m[0] for a in base.anchors])
    near = np.abs(east - east0) < 2.0
    far = np.abs(east - east0 - 40.0) < 2.0
    assert np.all(near | far) and near.any() and far.any()  # both recorded layouts, jittered
    assert len(ds.meta["scenario"]["variation"]["layouts"]) == 2


def test_transfer_drops_the_section(base):
    from physynth.calibrate import transfer_scenario

    scn = with_variation(base, path_yaw_std_rad=0.1)
    real = generate_trace(base, 0, SEED)
    assert transfer_scenario(scn, [real]).variation is None


@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="Dask (physynth[scale]) not installed")
def test_workers_on_a_local_cluster_give_the_same_varied_files(base, tmp_path):
    from physynth.workflows import generate_dataset

    scn = with_variation(base, layout_jitter_m=0.5, random_route_prob=0.5)
    one, _ = generate_dataset(scn, 5, tmp_path / "one", seed=SEED, shard_traces=2, workers=1)
    two, _ = generate_dataset(scn, 5, tmp_path / "two", seed=SEED, shard_traces=2, workers=2)
    files = sorted(p.relative_to(one) for p in one.rglob("*.parquet"))
    assert files and all((one / f).read_bytes() == (two / f).read_bytes() for f in files)
    assert len({tuple(t.anchors.pos_enu_m.ravel()) for t in read_dataset(two).traces}) == 5


def test_the_study_variation_replaces_a_section_of_the_scenario(base):
    study = SiteVariationParams(layout_jitter_m=0.5)
    with_section = with_variation(base, layout_jitter_m=5.0, path_shift_std_m=20.0)
    a, b = synthetic_trace(with_section, 1, SEED, study), synthetic_trace(base, 1, SEED, study)
    assert np.array_equal(a.anchors.pos_enu_m, b.anchors.pos_enu_m)  # drawn once, by the study's variation
    assert np.array_equal(a.truth.pos_enu_m, b.truth.pos_enu_m)


def test_nlos_frequency_varies_per_trace(base):
    """``nlos_log_std``: every trace's NLOS probabilities (each anchor's channel and the tag side) are its
    own draw exp(N(0, s)) times the scenario's; drawn last, so the other draws stay as they were; the
    tracking study's variation gives the scenario section's traces bit for bit."""
    from physynth.models.variation import NLOS_PROB_MAX, nlos_scaled

    study = SiteVariationParams(nlos_log_std=1.0)
    cs = compile_scenario(with_variation(base, **study.model_dump()))
    plain = compile_scenario(with_variation(base, **SiteVariationParams().model_dump()))
    scales, changed = [], []
    for i in range(12):
        a, b = synthetic_trace(base, i, SEED, study), generate_trace(cs, i, SEED)
        assert np.array_equal(a.uwb.range_m, b.uwb.range_m, equal_nan=True)
        c = generate_trace(plain, i, SEED)
        assert np.array_equal(b.truth.pos_enu_m, c.truth.pos_enu_m)  # the site's draws did not move
        scales.append(b.meta["site_variation"]["nlos_scale"])
        # the same trace as one of the scenario with its NLOS scaled by that draw and no draw of its own
        scaled = base.model_copy(update=nlos_scaled(base, scales[-1]))
        d = generate_trace(compile_scenario(with_variation(scaled, **SiteVariationParams().model_dump())), i, SEED)
        assert np.array_equal(b.uwb.range_m, d.uwb.range_m, equal_nan=True)
        changed.append(not np.array_equal(b.uwb.range_m, c.uwb.range_m, equal_nan=True))
    scales = np.array(scales)
    assert scales.min() < 0.7 and scales.max() > 1.4  # both ways over 12 draws at s = 1
    assert all(changed)  # and the ranges follow it
    assert all("nlos_scale" not in generate_trace(plain, i, SEED).meta["site_variation"] for i in range(2))
    upd = nlos_scaled(base, 3.0)
    assert upd["channel"].nlos_prob == pytest.approx(min(3.0 * base.channel.nlos_prob, NLOS_PROB_MAX))
    assert upd["uwb"].tag_nlos_prob == pytest.approx(min(3.0 * base.uwb.tag_nlos_prob, NLOS_PROB_MAX))
    assert all(upd["channel_per_anchor"][k].nlos_prob == (None if ch.nlos_prob is None else
               pytest.approx(min(3.0 * ch.nlos_prob, NLOS_PROB_MAX))) for k, ch in base.channel_per_anchor.items())
    rng = np.random.default_rng(5)
    v = SiteVariationParams(nlos_log_std=0.8)
    path = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [20, 0, 1]], "perturbation": {}}
    n = 600
    logs = np.log([draw_site(v, np.zeros((3, 3)), path, lambda: np.zeros((2, 3)), rng)[2]["nlos_scale"]
                   for _ in range(n)])
    assert np.std(logs) == pytest.approx(0.8, rel=4.0 / np.sqrt(2 * n)) and abs(np.mean(logs)) < 4 * 0.8 / np.sqrt(n)
