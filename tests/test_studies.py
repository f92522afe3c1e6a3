"""Deployment studies: regimes change exactly what they document, the anchor order follows availability,
more anchors never lower the >= 1 availability, outputs parse, placement, and one-line CLI errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import run_cli as run
from helpers import simple_scenario, simple_scenario_dict

from physynth import bounds
from physynth.cli.study import parse_counts
from physynth.errors import BudgetError, PhySynthError
from physynth.evaluate.metrics import compute_metrics
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario, save_scenario
from physynth.scenario import scenario_from_dict, scenario_to_dict
from physynth.studies.anchors import TRACKERS, AnchorStudy, TrackerColumn, run_anchor_study, write_anchor_study
from physynth.studies.placement import greedy_placement, read_candidates
from physynth.studies.regimes import REGIMES, apply_regime
from physynth.studies.subset import restrict_to_anchors


def _rated_scenario():
    """Three anchors of clearly different availability: A2 (15 Hz) > A3 (9 Hz) > A1 (4 Hz)."""
    return simple_scenario(**{"channel.rate_hz": 15.0,
                              "channel_per_anchor": {"A1": {"rate_hz": 4.0}, "A3": {"rate_hz": 9.0}},
                              "availability": {"dropout_prob": 0.1, "outage_onset_prob": 0.01,
                                               "outage_mean_s": 3.0}})


@pytest.fixture(scope="module")
def study():
    return run_anchor_study(_rated_scenario(), n=4, seed=3, regimes=("nominal", "sparse", "degraded"), workers=1)


def test_order_follows_availability(study):
    assert study.order == ["A2", "A3", "A1"]
    frac = study.order_availability
    assert frac["A2"] > frac["A3"] > frac["A1"]
    # measured on the reference run: the per-anchor fresh fractions of traces n .. 2n-1
    cs = compile_scenario(_rated_scenario())
    m = compute_metrics([generate_trace(cs, i, 3) for i in range(4, 8)])
    assert frac == {a: pytest.approx(m.per_anchor[a]["fresh_frac"], rel=1e-12) for a in ("A1", "A2", "A3")}


def test_order_from_a_real_dataset_and_explicit_order():
    scn = _rated_scenario()
    real = [generate_trace(compile_scenario(apply_regime(scn, "sparse")), i, 99) for i in range(2)]
    m = compute_metrics(real)
    s = run_anchor_study(scn, real=real, n=2, seed=1, counts=[1, 3], regimes=("nominal",), workers=1)
    assert s.order == sorted(["A1", "A2", "A3"], key=lambda a: -m.per_anchor[a]["fresh_frac"])
    assert s.reference["ge1"] == pytest.approx(m.uwb_ge1_frac)
    s2 = run_anchor_study(scn, n=2, seed=1, counts=[1], regimes=("nominal",), order=["A1", "A3", "A2"], workers=1)
    assert s2.order == ["A1", "A3", "A2"]
    # a real run of other anchors is no reference for this deployment, whatever the order given
    renamed = [a.model_copy(update={"id": f"B{i}"}) for i, a in enumerate(scn.anchors)]
    other = scn.model_copy(update={"anchors": renamed})
    foreign = [generate_trace(compile_scenario(other), 0, 99)]
    with pytest.raises(PhySynthError, match="anchor ids differ between the real dataset and scenario"):
        run_anchor_study(scn, real=foreign, n=2, seed=1, counts=[1], regimes=("nominal",), order=["A1", "A3", "A2"],
                         workers=1)


def test_more_anchors_never_lower_ge1_for_the_same_seed(study):
    for r in study.scores:
        ge1 = [study.availability[r][str(k)]["ge1"] for k in study.counts]
        ge2 = [study.availability[r][str(k)]["ge2"] for k in study.counts]
        assert ge1 == sorted(ge1) and ge2 == sorted(ge2), r
        assert ge1[-1] > ge1[0]
    # and trace by trace: a superset of anchors delivers a superset of fresh bins
    tr = generate_trace(compile_scenario(_rated_scenario()), 0, 3)
    fr = [compute_metrics([restrict_to_anchors(tr, ["A2", "A3", "A1"][:k])]).uwb_ge1_frac for k in (1, 2, 3)]
    assert fr == sorted(fr)


def test_workers_do_not_change_the_numbers():
    scn = _rated_scenario()
    a = run_anchor_study(scn, n=3, seed=5, counts=[1, 3], regimes=("dense",), workers=1)
    b = run_anchor_study(scn, n=3, seed=5, counts=[1, 3], regimes=("dense",), workers=2)
    assert a.scores == b.scores and a.availability == b.availability and a.order == b.order
    np.testing.assert_equal(a.columns, b.columns)  # GDOP and the trackers' errors too (NaN = NaN here)
    assert np.isfinite(a.columns["dense"][3]["ekf_median_m"])


def _flat(d, prefix=""):
    out = {}
    for k, v in (enumerate(d) if isinstance(d, list) else d.items()):
        key = f"{prefix}{k}"
        if isinstance(v, (dict, list)) and v:
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


@pytest.mark.parametrize("regime", sorted(REGIMES))
def test_a_regime_changes_exactly_the_parameters_it_documents(regime):
    scn = load_scenario("cablecar-descending")
    new = apply_regime(scn, regime)
    documented = {c.field: c for c in REGIMES[regime]}
    # every resolved per-anchor channel and availability value, and every zone
    for a in scn.anchor_ids:
        for section, get in (("channel", "channel_for"), ("availability", "availability_for")):
            before = getattr(scn, get)(a).model_dump()
            after = getattr(new, get)(a).model_dump()
            for fld, v in before.items():
                ch = documented.get(f"{section}.{fld}")
                if ch is None:
                    assert after[fld] == v, (regime, a, section, fld)
                    continue
                assert after[fld] == pytest.approx(ch.apply(v, scn.uwb.burst_rate_hz)), (regime, a, section, fld)
                if ch is not None and ch.op != "set_burst_rate":
                    assert after[fld] != v or (ch.cap is not None and v >= ch.cap)
    for zb, za in zip(scn.uwb.zones, new.uwb.zones, strict=True):
        ch = documented.get("uwb.zones.nlos_prob")
        assert za.nlos_prob == pytest.approx(zb.nlos_prob if ch is None else ch.apply(zb.nlos_prob, 23.0))
    # nothing else in the scenario moved (bookkeeping aside)
    fb, fa = _flat(scenario_to_dict(scn)), _flat(scenario_to_dict(new))
    changed = {k for k in fb if fb[k] != fa.get(k)} | (set(fa) - set(fb))
    allowed_roots = {f.split(".")[0] for f in documented}
    for k in changed:
        root = k.split(".")[0].replace("_per_anchor", "")
        assert root in allowed_roots | {"name", "provenance"}, (regime, k)
        leaf = k.split(".")[-1]
        assert k.startswith(("name", "provenance")) or any(f.endswith("." + leaf) for f in documented), (regime, k)
    assert (new is scn) == (regime == "nominal")


def test_dense_regime_through_generate_matches_the_library(tmp_path, capsys):
    code, _, _ = run(capsys, "generate", "-n", 1, "--seed", 4, "--regime", "dense", "--out", tmp_path / "d", "-q")
    assert code == 0
    from physynth.io import read_dataset

    ds = read_dataset(tmp_path / "d")
    ref = generate_trace(compile_scenario(apply_regime(load_scenario("cablecar-descending"), "dense")), 0, 4)
    np.testing.assert_array_equal(ds.traces[0].uwb.range_m, ref.uwb.range_m)
    assert ds.meta["scenario"]["provenance"]["regime"]["name"] == "dense"


def test_table_files_parse(study, tmp_path):
    written = write_anchor_study(study, tmp_path, figures=True)
    assert written == ["table.json", "table.md", "anchors.png"]
    d = json.loads((tmp_path / "table.json").read_text())
    assert set(d) >= {"scores", "availability", "order", "regimes", "reference", "columns"}
    assert d["order"] == study.order
    assert set(d["scores"]) == {"nominal", "sparse", "degraded"}
    for r, row in d["scores"].items():
        assert {int(k) for k in row} == {1, 2, 3}
        assert all(isinstance(v, float) and v >= 0 for v in row.values())
        assert set(d["availability"][r]["3"]) >= {"ge1", "ge2"}
    assert set(d["regimes"]["degraded"]) == {"summary", "changes"}
    md = (tmp_path / "table.md").read_text().splitlines()
    head = md.index("| Anchors | Nominal | Sparse | Degraded | Mean |")
    rows = [line.split("|")[1].strip() for line in md[head + 2:head + 6]]
    assert rows == ["3", "2", "1", "Mean"]
    cells = md[head + 2].split("|")[2:5]
    assert [float(c) for c in cells] == pytest.approx([study.scores[r][3] for r in ("nominal", "sparse", "degraded")],
                                                      abs=5e-4)
    assert (tmp_path / "anchors.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    back = AnchorStudy.from_dict(d)
    assert back.scores == study.scores and back.order == study.order and back.counts == study.counts
    with pytest.raises(PhySynthError, match="already holds an anchor study"):
        write_anchor_study(study, tmp_path)


def test_tracker_column(study, tmp_path):
    """ls and ekf errors per cell: present, sane, and what holds by construction under common random numbers."""
    for r in study.scores:
        fix = {t: [study.columns[r][k][f"{t}_fix_frac"] for k in study.counts] for t in TRACKERS}
        for t in TRACKERS:
            # more anchors: the first range (ls) and the first step with three ranged anchors (ekf) come no later
            assert fix[t] == sorted(fix[t]) and all(0.0 <= f <= 1.0 for f in fix[t]), (r, t)
        assert fix["ekf"][:2] == [0.0, 0.0] and fix["ekf"][2] > 0.9  # the ekf starts on three anchors
        assert fix["ls"][0] > 0.9
        for k in study.counts:
            c = study.columns[r][k]
            assert c["tracker_traces"] == 4  # min(n, TRACKER_TRACES)
            for t in TRACKERS:
                if c[f"{t}_fix_frac"] > 0:
                    assert 0 <= c[f"{t}_h_median_m"] <= c[f"{t}_h_p95_m"] and c[f"{t}_median_m"] <= c[f"{t}_p95_m"]
                    assert c[f"{t}_h_median_m"] <= c[f"{t}_median_m"] + 1e-9
                else:
                    assert np.isnan(c[f"{t}_median_m"])
    # nominal: exact ranges (1e-12 m) from three anchors 20 m off the line at 3 m height, tag at 1 m, 3 m/s,
    # a range per anchor every 1/15 s (dropouts 10 %): horizontally the ekf lags by at most a few range
    # periods of motion; in height it may sit on the mirror fix across the anchors' plane (3 + 2 m)
    c = study.columns["nominal"][3]
    assert c["ekf_h_median_m"] < 3.0 * 3.0 / 15.0
    assert c["ekf_median_m"] < 2 * (3.0 - 1.0) + 3.0 * 3.0 / 15.0
    write_anchor_study(study, tmp_path, figures=False)
    d = json.loads((tmp_path / "table.json").read_text())
    assert {"ls_median_m", "ekf_p95_m", "ekf_h_rmse_m", "ekf_fix_frac"} <= set(d["columns"]["nominal"]["3"])
    md = (tmp_path / "table.md").read_text()
    assert "Tracker position error, 3-D [m]" in md and "| nominal ls | nominal ekf |" in md


def test_command_line_default_of_tracker_traces_is_the_library_one():
    import inspect

    from physynth.cli.study import anchors_cmd
    from physynth.studies.anchors import TRACKER_TRACES

    assert inspect.signature(anchors_cmd).parameters["tracker_traces"].default.default == TRACKER_TRACES


def test_tracker_column_on_the_cable_car_beats_knowing_nothing():
    """With all six anchors the ekf's median error is below that of the estimate 'at the anchor centroid'."""
    scn = load_scenario("cablecar-descending")
    s = run_anchor_study(scn, n=1, seed=2, counts=[2, 6], regimes=("dense",), workers=1,
                         columns=(TrackerColumn(),))
    tr = generate_trace(compile_scenario(apply_regime(scn, "dense")), 0, 2)
    centroid = tr.anchors.pos_enu_m.mean(axis=0)
    know_nothing = float(np.median(np.linalg.norm(tr.truth.pos_enu_m - centroid, axis=1)))
    six = s.columns["dense"][6]
    assert six["ekf_fix_frac"] > 0.5 and six["ekf_median_m"] < know_nothing
    assert s.columns["dense"][2]["ekf_fix_frac"] == 0.0  # two anchors: no 3-D fix to start from


def test_gdop_column(study):
    one, three = study.columns["nominal"][1], study.columns["nominal"][3]
    assert one["gdop_le5_frac"] == 0.0 and not np.isfinite(one["gdop_median"])  # one anchor: no fix
    assert not np.isfinite(one["fresh_hdop_median"])
    assert np.isfinite(three["gdop_median"]) and np.isfinite(three["fresh_hdop_median"])


def test_gdop_against_closed_forms():
    from physynth.studies.dop import gdop

    # three orthogonal unit directions: H = I, GDOP = sqrt(3); the 2-D part of two orthogonal ones: sqrt(2)
    tag = np.zeros((1, 3))
    anchors = np.array([[-10.0, 0, 0], [0, -10.0, 0], [0, 0, -10.0]])
    assert gdop(tag, anchors)[0] == pytest.approx(np.sqrt(3))
    assert gdop(tag, anchors[:2], known_height=True)[0] == pytest.approx(np.sqrt(2))
    # anchors in one plane with the tag: no 3-D fix; two anchors in line with the tag: no 2-D fix
    flat = np.array([[10.0, 0, 0], [0, 10.0, 0], [-10.0, 0, 0]])
    assert not np.isfinite(gdop(tag, flat)[0])
    assert not np.isfinite(gdop(tag, flat[[0, 2]], known_height=True)[0])
    mask = np.array([[True, True, False]])
    assert not np.isfinite(gdop(tag, anchors, mask)[0])


def test_greedy_placement_picks_the_anchors_that_cover_the_path(tmp_path):
    # the path runs E 0..300 at N 0; candidates near the route beat far ones under a link budget
    scn = simple_scenario(**{"channel.link_budget": {"ref_power_dbm": -40.0, "sensitivity_dbm": -80.0,
                                                     "shadowing_std_db": 2.0},
                             "path": {"kind": "waypoints", "waypoints_enu_m": [[0, 0, 1], [300, 0, 1]],
                                      "perturbation": {"lateral_std_m": 0.0, "sag_std_m": 0.0}}})
    (tmp_path / "c.csv").write_text("id,e,n,u\nnear0,50,5,3\nfar,150,400,3\nnear1,150,5,3\nnear2,250,5,3\n"
                                    "dup,52,5,3\n")
    cands = read_candidates(tmp_path / "c.csv")
    p = greedy_placement(scn, cands, k=3, n=3, seed=2, workers=1)
    # one anchor per stretch of the route ("dup" stands 2 m from "near0": either of them), never "far"
    assert {"near1", "near2"} <= set(p.chosen) and len({"near0", "dup"} & set(p.chosen)) == 1
    obj = [s["objective"] for s in p.steps]
    assert obj == sorted(obj)  # ge1 never falls as anchors are added
    assert [a.id for a in p.scenario.anchors] == p.chosen
    # anchors on one line beside the route see the tag in one plane: no 3-D fix, every point at the cap
    g = greedy_placement(scn, cands, k=3, n=2, seed=2, objective="gdop", workers=1)
    assert g.steps[-1]["objective"] == 10.0
    (tmp_path / "c2.csv").write_text("id,e,n,u\nlow,150,5,3\nhigh,150,10,25\nside,150,-30,3\nfar,150,400,3\n")
    g = greedy_placement(scn, read_candidates(tmp_path / "c2.csv"), k=3, n=2, seed=2, objective="gdop", workers=1)
    assert set(g.chosen) == {"low", "high", "side"} and g.steps[-1]["objective"] < 10.0


@pytest.mark.parametrize(("args", "needle"), [
    (["study", "anchors", "--counts", "0..9"], "anchor counts must lie in 1..6"),
    (["study", "anchors", "--counts", "two"], "--counts: expected a range"),
    (["study", "anchors", "--regimes", "dense,foggy"], "unknown regime 'foggy'"),
    (["study", "anchors", "--order", "A101,X9"], "unknown anchor(s) X9"),
    (["study", "anchors", "-n", "0"], "greater than or equal to 1"),
    (["study", "anchors", "--real", "/nonexistent/ds"], "real dataset"),
    (["generate", "--regime", "foggy"], "unknown regime 'foggy'"),
    (["generate", "-s", "handheld-broad", "--regime", "sparse"], "scenario 'handheld-broad' has no anchors"),
    (["study", "placement", "--candidates", "/nonexistent.csv", "-k", "2"], "does not exist"),
])
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, args, needle):
    if args[0] == "study" and "--out" not in args:
        args = [*args, "--out", str(tmp_path / "o"), "-q"]
    else:
        args = [*args, "--out", str(tmp_path / "o"), "-q"]
    code, _, err = run(capsys, *args)
    assert code == 2, err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


def test_cli_placement_bad_candidates_and_k(tmp_path, capsys):
    (tmp_path / "c.csv").write_text("id,e,n\nA,1,2\n")
    code, _, err = run(capsys, "study", "placement", "--candidates", tmp_path / "c.csv", "-k", 1, "--out",
                       tmp_path / "o", "-q")
    assert code == 2 and "id,e,n,u" in err and err.count("\n") == 1
    (tmp_path / "c.yaml").write_text("- {id: A, pos_enu_m: [1, 2, 3]}\n")
    code, _, err = run(capsys, "study", "placement", "--candidates", tmp_path / "c.yaml", "-k", 2, "--out",
                       tmp_path / "o", "-q")
    assert code == 2 and "must lie in 1..1" in err


def test_cli_study_anchors_and_validate_subset(tmp_path, capsys):
    scn_path = save_scenario(_rated_scenario(), tmp_path / "s.yaml")
    code, out, err = run(capsys, "study", "anchors", "-s", scn_path, "-n", 2, "--seed", 1, "--counts", "1..3",
                         "--regimes", "nominal", "--workers", 1, "--no-figures", "--out", tmp_path / "st")
    assert code == 0, err
    assert "order: A2, A3, A1" in out
    assert json.loads((tmp_path / "st" / "table.json").read_text())["scores"]["nominal"]["3"] >= 0
    # validate --anchors: a one-anchor synthetic side against the full (three-anchor) real dataset
    code, _, err = run(capsys, "generate", "-s", scn_path, "-n", 2, "--seed", 8, "--out", tmp_path / "real", "-q")
    assert code == 0, err
    code, out, err = run(capsys, "validate", "--real", tmp_path / "real", "--scenario", scn_path, "-n", 2,
                         "--seed", 1, "--anchors", "A2", "--no-figures", "--out", tmp_path / "rep")
    assert code == 0, err
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert rep["inputs"]["anchor_subset"] == ["A2"]
    assert rep["per_anchor"]["A1"]["synthetic"] is None and rep["per_anchor"]["A2"]["synthetic"] is not None
    code, _, err = run(capsys, "validate", "--real", tmp_path / "real", "--scenario", scn_path, "-n", 1,
                       "--anchors", "A2,Q", "--no-figures", "--out", tmp_path / "rep2", "-q")
    assert code == 2 and "unknown anchor(s) Q" in err and err.count("\n") == 1


def test_helpers_roundtrip():
    d = simple_scenario_dict()
    assert scenario_to_dict(scenario_from_dict(d))["anchors"][0]["id"] == "A1"


def test_counts_beyond_the_anchors_fail_at_once_in_one_short_line(tmp_path, capsys):
    with pytest.raises(PhySynthError, match=r"1\.\.6 \(the scenario's anchors\), got 2\.\.1000000000000$"):
        parse_counts("1,2..1000000000000", 6)  # refused before the range is expanded
    assert parse_counts("1..3,6", 6) == [1, 2, 3, 6]
    code, _, err = run(capsys, "study", "anchors", "--counts", "1..100000", "-n", 1, "--out", tmp_path / "o", "-q")
    assert code == 2 and err.count("\n") == 1 and len(err) < 200 and "got 1..100000" in err
    with pytest.raises(PhySynthError) as exc:  # the library names a few of the counts, not all of them
        run_anchor_study(_rated_scenario(), n=1, counts=range(1, 100_000), regimes=("nominal",), workers=1)
    assert len(str(exc.value)) < 200 and "(99996 in all)" in str(exc.value)
    assert not (tmp_path / "o").exists()


def test_studies_refuse_a_size_over_budget_unless_forced(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bounds, "OUTPUT_BUDGET_BYTES", 1.0)  # every study is over it
    scn = _rated_scenario()
    with pytest.raises(BudgetError, match="2 trace"):  # one regime and the reference run
        run_anchor_study(scn, n=1, counts=[1], regimes=("nominal",), workers=1)
    assert run_anchor_study(scn, n=1, counts=[1], regimes=("nominal",), workers=1, force=True).scores
    (tmp_path / "c.csv").write_text("id,e,n,u\nP1,50,20,3\nP2,250,20,3\n")
    cands = read_candidates(tmp_path / "c.csv")
    with pytest.raises(BudgetError, match="4 trace"):  # selection and held-out traces
        greedy_placement(scn, cands, k=1, n=2, workers=1)
    scn_path = save_scenario(scn, tmp_path / "s.yaml")
    commands = (["study", "anchors", "-s", scn_path, "-n", 1, "--counts", 1, "--regimes", "nominal",
                 "--tracker-traces", 0, "--workers", 1, "--no-figures", "-q"],
                ["study", "placement", "-s", scn_path, "--candidates", tmp_path / "c.csv", "-k", 1, "-n", 1,
                 "--workers", 1, "--no-figures", "-q"])
    for j, args in enumerate(commands):
        code, _, err = run(capsys, *args, "--out", tmp_path / f"o{j}")
        assert code == 2 and err.count("\n") == 1 and "budget" in err and "use --force" in err, err
        assert not (tmp_path / f"o{j}").exists()
        code, _, err = run(capsys, *args, "--force", "--out", tmp_path / f"o{j}")
        assert code == 0, err


def test_cli_study_anchors_summary_fits_80_columns(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    code, out, err = run(capsys, "study", "anchors", "-n", 1, "--seed", 1, "--counts", 1, "--regimes", "nominal",
                         "--tracker-traces", 0, "--workers", 1, "--no-figures", "--out", tmp_path / "st")
    assert code == 0, err
    assert max(len(line) for line in out.splitlines()) <= 79, out
    assert "(by reference-run availability)" in out and "reference: reference run" not in out
    assert "wall time" in out  # on the last line, wrapped like the others: the output folder's path is long
