"""A scenario for a surveyed site: the anchors and route of the survey, the channel of another site."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from helpers import simple_scenario

from physynth.cli import main
from physynth.errors import ScenarioError
from physynth.generate import generate_trace
from physynth.io.scenario_file import load_scenario
from physynth.survey import survey_scenario

SURVEY = (["S1", "S2", "S3", "S4"], [[10, 0, 2.0], [14, 0, 2.0], [14, 3, 0.5], [10, 3, 1.2]])


def _base():
    return simple_scenario(**{"channel_per_anchor": {"A1": {"los_std_m": 0.3}}})


def test_the_site_takes_the_survey_and_the_other_sites_channel():
    base = _base()
    assert base.anchors[0].id == "A1"  # the base's own anchors have channels of their own
    scn = survey_scenario(base, *SURVEY)
    assert [a.id for a in scn.anchors] == SURVEY[0] and scn.channel_per_anchor == {}
    assert np.allclose([a.pos_enu_m for a in scn.anchors], SURVEY[1])
    assert scn.channel == base.channel and scn.uwb == base.uwb and scn.imu == base.imu
    shift = np.mean(SURVEY[1], axis=0)[:2] - np.mean([a.pos_enu_m for a in base.anchors], axis=0)[:2]
    moved = np.asarray(scn.path.waypoints_enu_m) - np.asarray(base.path.waypoints_enu_m)
    assert np.allclose(moved[:, :2], shift) and np.allclose(moved[:, 2], 0)  # the path moved with the anchors
    trace = generate_trace(scn, 0, 1)
    assert trace.anchors.ids == tuple(SURVEY[0]) and trace.uwb.valid.any()
    routed = survey_scenario(base, *SURVEY, route_enu_m=[[0, 0, 1], [30, 5, 1]])
    assert routed.path.kind == "waypoints" and routed.path.waypoints_enu_m[-1] == [30, 5, 1]


@pytest.mark.parametrize(("ids", "pos", "route", "needle"), [
    (["a", "b"], [[0, 0, 1], [1, 0, 1]], None, "three or more"),
    (["a", "b", "a"], [[0, 0, 1], [1, 0, 1], [0, 1, 1]], None, "ids repeat: a"),
    (["a", "b", "c"], [[0, 0, 1], [1, 0, 1]], None, "one [E, N, U] position per anchor"),
    (["a", "b", "c"], [[0, 0, 1], [1, 0, np.nan], [0, 1, 1]], None, "finite"),
    (["a", "b", "c"], [[0, 0, 1], [1, 0, 1], [0, 1, 1]], [[0, 0, 1]], "two or more finite"),
])
def test_bad_surveys_are_refused(ids, pos, route, needle):
    with pytest.raises(ScenarioError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        survey_scenario(_base(), ids, pos, route)


def test_cli_writes_the_site_scenario(tmp_path, capsys):
    base = tmp_path / "base.yaml"
    base.write_text(yaml.safe_dump(__import__("physynth").scenario_to_dict(_base())))
    (tmp_path / "a.csv").write_text("id, e, n, u\n" + "".join(f"{i},{p[0]},{p[1]},{p[2]}\n"
                                                              for i, p in zip(*SURVEY, strict=True)))
    (tmp_path / "r.csv").write_text("E,N,U\n0,0,1\n20,2,1\n")
    main(["scenario", "survey", str(base), "--anchors", str(tmp_path / "a.csv"), "--route", str(tmp_path / "r.csv"),
          "--out", str(tmp_path / "site.yaml")])
    scn = load_scenario(tmp_path / "site.yaml")
    assert [a.id for a in scn.anchors] == SURVEY[0] and scn.path.waypoints_enu_m[1] == [20, 2, 1]
    (tmp_path / "bad.csv").write_text("id,e,n,u\nS1,1,2,x\n")
    for args, needle in [(["--anchors", tmp_path / "bad.csv", "--out", tmp_path / "o.yaml"], "row 2 has no number"),
                         (["--anchors", tmp_path / "r.csv", "--out", tmp_path / "o.yaml"], "lacks the column(s) id"),
                         (["--anchors", tmp_path / "none.csv", "--out", tmp_path / "o.yaml"], "does not exist"),
                         (["--anchors", tmp_path / "a.csv", "--out", tmp_path / "site.yaml"], "--overwrite")]:
        with pytest.raises(SystemExit) as exc:
            main(["scenario", "survey", str(base), *map(str, args)])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "o.yaml").exists()
