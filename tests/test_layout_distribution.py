"""``variation.layout_distribution``: whole anchor layouts drawn per trace (models/variation.py)."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from physynth.bounds import estimate_size
from physynth.errors import ScenarioError
from physynth.generate import compile_scenario, generate_trace, generate_traces, vary_site
from physynth.io.scenario_file import load_scenario
from physynth.models.variation import (
    LayoutDistribution,
    SiteVariationParams,
    draw_layout,
    draw_site,
    sample_layout,
)
from physynth.rng import COMPONENT_ID
from physynth.scenario import Scenario, scenario_from_dict, scenario_to_dict
from physynth.track.synth import synthetic_trace

SEED = 23
WIDE = {"anchor_count": [3, 8], "footprint_m": [2.0, 12.0], "aspect": [0.2, 0.9], "height_m": [0.3, 2.5],
        "coplanar_prob": 0.4, "coplanar_std_m": 0.03, "min_spacing_m": 0.4, "route_offset_m": [0.5, 3.0]}


@pytest.fixture(scope="module")
def cablecar() -> Scenario:
    """Six anchors, each with its own channel; three with availability overrides of their own, made distinct."""
    d = scenario_to_dict(load_scenario("cablecar-descending"))
    for k, aid in enumerate(d["availability_per_anchor"]):
        d["availability_per_anchor"][aid]["dropout_prob"] = 0.01 * (k + 1)
    return scenario_from_dict(d, "cablecar with distinct availabilities")


def with_variation(scn: Scenario, **kw) -> Scenario:
    d = scenario_to_dict(scn)
    d["variation"] = kw
    return scenario_from_dict(d, "test")


def draws(dist: LayoutDistribution, n: int, seed: int = 0, centre=(10.0, -5.0, 7.0)):
    rng = np.random.default_rng(seed)
    out = [sample_layout(dist, np.asarray(centre), rng) for _ in range(n)]
    return [p for p, _ in out], [r for _, r in out]


def test_draws_stay_within_their_ranges_and_match_their_record():
    dist = LayoutDistribution(**WIDE)
    centre = np.array([10.0, -5.0, 7.0])
    pos, rec = draws(dist, 600, centre=centre)
    counts = np.array([len(p) for p in pos])
    assert set(counts) == set(range(3, 9))  # every count of the range is met
    assert all(r["anchor_count"] == len(p) for p, r in zip(pos, rec, strict=True))
    for p, r in zip(pos, rec, strict=True):
        c, s = np.cos(r["yaw_rad"]), np.sin(r["yaw_rad"])
        local = (p[:, :2] - p[:, :2].mean(axis=0)) @ np.array([[c, -s], [s, c]])  # turned back by the yaw
        extent = np.ptp(local, axis=0)
        assert extent[0] == pytest.approx(r["footprint_m"], abs=1e-9)  # the footprint is the long side exactly
        assert extent[1] == pytest.approx(r["aspect"] * r["footprint_m"], abs=1e-9)
        assert 2.0 <= r["footprint_m"] <= 12.0 and 0.2 <= r["aspect"] <= 0.9
        assert np.all((p[:, 2] >= 0.3) & (p[:, 2] <= 2.5))
        gaps = np.linalg.norm(p[:, None] - p[None], axis=2)[~np.eye(len(p), dtype=bool)]
        assert gaps.min() >= 0.4
        offset = p[:, :2].mean(axis=0) - centre[:2]
        assert np.allclose(offset, r["offset_m"], atol=1e-9) and 0.5 <= np.hypot(*offset) <= 3.0
    fp = np.array([r["footprint_m"] for r in rec])
    assert fp.min() < 3.0 and fp.max() > 11.0  # the range is spanned, not a corner of it
    yaw = np.mod([r["yaw_rad"] for r in rec], 2 * np.pi)
    assert np.all(np.histogram(yaw, bins=4, range=(0, 2 * np.pi))[0] > 600 / 4 - 4 * np.sqrt(600 * 3 / 16))


def test_coplanar_share_is_coplanar_prob():
    """With a spacing every shape meets, the coplanar share is binomial(n, coplanar_prob); coplanar layouts
    hang at one height, the others are spread."""
    n, p = 2000, 0.4
    pos, rec = draws(LayoutDistribution(**{**WIDE, "min_spacing_m": 0.1}), n, seed=3)
    assert all(r["shapes"] == 1 for r in rec)  # no shape was redrawn: the share is not conditioned
    flags = np.array([r["coplanar"] for r in rec])
    assert abs(flags.mean() - p) < 4 * np.sqrt(p * (1 - p) / n)
    spread = np.array([np.std(q[:, 2]) for q in pos])
    assert spread[flags].max() < 5 * 0.03 and np.median(spread[~flags]) > 0.3
    # the defaults: a few crowded shapes are redrawn; the share stays within the binomial tolerance
    _, rec = draws(LayoutDistribution(), n, seed=4)
    assert abs(np.mean([r["coplanar"] for r in rec]) - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n)


def test_draw_layout_is_a_pure_function_of_its_generator():
    dist = LayoutDistribution(**WIDE)
    a = draw_layout(dist, np.zeros(3), np.random.default_rng(9))
    b = draw_layout(dist, np.zeros(3), np.random.default_rng(9))
    c = draw_layout(dist, np.zeros(3), np.random.default_rng(10))
    assert np.array_equal(a, b) and a.shape[1] == 3 and not np.array_equal(a, c)


def test_impossible_spacing_is_refused_clearly():
    crowded = LayoutDistribution(anchor_count=[8, 8], footprint_m=[1.5, 1.5], min_spacing_m=2.0)
    with pytest.raises(ScenarioError, match=r"no layout of 8-8 anchors .* 2 m apart .*lower min_spacing_m"):
        draw_layout(crowded, np.zeros(3), np.random.default_rng(0))
    with pytest.raises(ValidationError, match="exceeds the largest distance two anchors can have"):
        LayoutDistribution(footprint_m=[1.0, 2.0], aspect=[0.0, 0.5], height_m=[1.0, 1.0], min_spacing_m=3.0)


@pytest.mark.parametrize(("field", "value", "message"), [
    ("anchor_count", [5, 4], "min <= max"),
    ("anchor_count", [2, 5], "greater than or equal to 3"),
    ("anchor_count", [3, 9], "less than or equal to 8"),
    ("footprint_m", [10.0, 2.0], "min <= max"),
    ("aspect", [0.5, 1.5], "less than or equal to 1"),
    ("height_m", [3.0, 0.2], "min <= max"),
    ("route_offset_m", [-1.0, 2.0], "greater than or equal to 0"),
    ("footprint_m", [1.0, 2000.0], r"variation\.layout_distribution\.footprint_m\[1\]: 2000 m is outside"),
    ("coplanar_prob", 1.5, "less than or equal to 1"),
    ("footprint_m", [1.0], "at least 2 items"),
])
def test_bad_distributions_are_one_clear_error(cablecar, field, value, message):
    with pytest.raises(ScenarioError, match=message) as exc:
        with_variation(cablecar, layout_distribution={field: value})
    assert "variation.layout_distribution" in str(exc.value) and "\n" not in str(exc.value)


def test_a_scenario_without_anchors_is_refused():
    imu_only = load_scenario("handheld-broad")
    with pytest.raises(ScenarioError, match="layout_distribution needs anchors"):
        with_variation(imu_only, layout_distribution={})
    v = SiteVariationParams(layout_distribution=LayoutDistribution())
    path = {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [20, 0, 1]], "perturbation": {}}
    with pytest.raises(ScenarioError, match="needs a scenario with anchors"):
        draw_site(v, np.zeros((0, 3)), path, lambda: np.zeros((2, 3)), np.random.default_rng(0))


def test_traces_have_anchor_counts_of_their_own_and_valid_rows(cablecar):
    scn = with_variation(cablecar, layout_distribution=WIDE)
    traces = list(generate_traces(scn, 10, seed=SEED))
    counts = [len(t.anchors) for t in traces]
    assert len(set(counts)) >= 3 and min(counts) >= 3 and max(counts) <= 8
    for t in traces:
        rec = t.meta["site_variation"]
        n = len(t.anchors)
        assert rec["layout"] is None and rec["layout_drawn"]["anchor_count"] == n
        assert t.anchors.ids == tuple(f"L{j + 1}" for j in range(n)) and t.anchors.names == t.anchors.ids
        assert len(rec["layout_drawn"]["pool"]) == n and all(0 <= k < 6 for k in rec["layout_drawn"]["pool"])
        assert t.uwb.anchor.size > 0 and t.uwb.anchor.min() >= 0 and t.uwb.anchor.max() < n
        assert set(np.unique(t.uwb.anchor)) == set(range(n))  # every drawn anchor ranges
        ok = np.isfinite(t.uwb.range_m) & np.isfinite(t.uwb.true_range_m)
        tag = np.array([np.interp(t.uwb.t_s, t.truth.t_s, t.truth.pos_enu_m[:, k]) for k in range(3)]).T
        true = np.linalg.norm(tag - t.anchors.pos_enu_m[t.uwb.anchor], axis=1)
        assert np.allclose(t.uwb.true_range_m[ok], true[ok], atol=0.5)  # rows measure the drawn anchors
    assert estimate_size(scn, 10).uwb_rows >= max(t.uwb.t_s.size for t in traces)
    assert estimate_size(scn, 1).uwb_rows == estimate_size(cablecar, 1).uwb_rows * 8 // 6


def test_per_trace_seeding_is_unchanged(cablecar):
    """Trace i draws its site from SeedSequence(root, spawn_key=(i, site)): alone or among others, the same."""
    scn = with_variation(cablecar, layout_distribution=WIDE, random_route_prob=0.5)
    many = list(generate_traces(scn, 5, seed=SEED))
    alone = next(generate_traces(scn, 1, seed=SEED, start=3))
    assert alone.anchors.ids == many[3].anchors.ids
    assert np.array_equal(alone.anchors.pos_enu_m, many[3].anchors.pos_enu_m)
    assert np.array_equal(alone.uwb.range_m, many[3].uwb.range_m, equal_nan=True)
    assert np.array_equal(alone.truth.pos_enu_m, many[3].truth.pos_enu_m)
    rng = np.random.default_rng(np.random.SeedSequence(SEED, spawn_key=(3, COMPONENT_ID["site"])))
    want = draw_layout(LayoutDistribution(**WIDE), np.mean([a.pos_enu_m for a in cablecar.anchors], axis=0), rng)
    assert np.array_equal(want, many[3].anchors.pos_enu_m)  # the layout is the stream's first draw
    assert len({len(t.anchors) for t in many}) > 1


def test_each_drawn_anchor_takes_a_pool_anchors_channel_and_availability(cablecar):
    """Every drawn anchor gets the resolved channel and availability of its pool anchor, in the compiled
    scenario and in its tables; over traces each pool anchor is used."""
    cs = compile_scenario(with_variation(cablecar, layout_distribution=WIDE))
    plain = compile_scenario(cablecar)
    pool_channels = [cablecar.channel_for(a) for a in cablecar.anchor_ids]
    assert len({c.model_dump_json() for c in pool_channels}) == 6  # distinct: a mix-up would show
    used = set()
    for i in range(8):
        compiled, rec = vary_site(cs, i, SEED)
        pool = rec["layout_drawn"]["pool"]
        used |= set(pool)
        assert compiled.anchors.ids == compiled.scenario.anchor_ids
        for j, aid in enumerate(compiled.scenario.anchor_ids):
            src = cablecar.anchor_ids[pool[j]]
            assert compiled.scenario.channel_for(aid) == cablecar.channel_for(src) in pool_channels
            assert compiled.scenario.availability_for(aid) == cablecar.availability_for(src)
        rows = np.asarray(pool)
        for f in ("los_mean_m", "los_std_m", "nlos_prob", "attempt_prob", "mode_mean_m", "mode_cumw", "max_range_m"):
            assert np.array_equal(getattr(compiled.channel, f), getattr(plain.channel, f)[rows]), f
        for f in ("dropout_prob", "outage_onset_prob", "outage_mean_s"):
            assert np.array_equal(getattr(compiled.availability, f), getattr(plain.availability, f)[rows]), f
        assert np.array_equal(compiled.channel.anchor_pos_enu_m, compiled.anchors.pos_enu_m)
    assert used == set(range(6))


def test_per_anchor_arrays_follow_the_drawn_count():
    """Run-to-run per-anchor offsets, the tag-side NLOS, a link budget and antenna boresights: all sized by
    the drawn layout; a boresight turns with the layout."""
    d = scenario_to_dict(load_scenario("walk-hanyang"))
    d["channel"]["link_budget"] = {}
    for k, a in enumerate(d["anchors"]):
        a["boresight_enu"], a["front_back_db"] = [1.0, float(k), 0.0], 6.0
    d["uwb"]["run_anchor_offset_std_m"], d["uwb"]["run_anchor_slope_std_m"] = 0.05, 0.02
    base = scenario_from_dict(d, "walk with antennas")
    study = SiteVariationParams(layout_distribution={**WIDE, "anchor_count": [5, 8]})
    cs = compile_scenario(with_variation(base, **study.model_dump()))
    for i in range(3):
        compiled, rec = vary_site(cs, i, SEED)
        n = rec["layout_drawn"]["anchor_count"]
        assert n >= 5 and compiled.channel.link.boresight_enu.shape == (n, 3)
        assert compiled.channel.tag_join.shape == (n,)
        yaw, pool = rec["layout_drawn"]["yaw_rad"], rec["layout_drawn"]["pool"]
        src = np.array([[1.0, float(k), 0.0] for k in pool])
        src /= np.linalg.norm(src, axis=1, keepdims=True)
        c, s = np.cos(yaw), np.sin(yaw)
        assert np.allclose(compiled.channel.link.boresight_enu, src @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]))
        t = generate_trace(cs, i, SEED)
        assert len(t.anchors) == n and t.uwb.anchor.max() < n
        assert np.array_equal(t.uwb.range_m, synthetic_trace(base, i, SEED, study).uwb.range_m, equal_nan=True)


def test_without_a_distribution_nothing_changes(cablecar):
    assert SiteVariationParams().layout_distribution is None
    assert SiteVariationParams(layout_distribution={"anchor_count": [4, 4]}).layout_distribution == \
        LayoutDistribution(anchor_count=[4, 4])
    with pytest.raises(ValidationError, match="layout_distribution"):
        SiteVariationParams(layout_distribution=[3, 4])
    t = generate_trace(with_variation(cablecar, layout_jitter_m=0.2), 1, SEED)
    assert "layout_drawn" not in t.meta["site_variation"] and t.anchors.ids == cablecar.anchor_ids
