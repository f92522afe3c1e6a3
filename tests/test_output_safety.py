"""``physynth export``, ``study`` and ``generate`` never lose data they did not write nor leave a run behind
(docs/reliability.md).

Every case runs the real command line on a real dataset and checks both the exit code (2, one line)
and that the user's files are still there, byte for byte.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings

import pytest

from physynth.cli import main
from physynth.errors import PhySynthWarning
from physynth.io.export import export_dataset
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path, _ = generate_dataset(load_scenario("cablecar-descending"), 2, tmp_path_factory.mktemp("exs") / "ds", seed=3)
    return path


def _refused(argv: list[str], capsys, needle: str) -> None:
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and needle in err and err.count("\n") == 1, err


def test_overwrite_replaces_only_exports(dataset, tmp_path, capsys):
    precious = tmp_path / "precious.h5"
    precious.write_bytes(b"not physynth")
    _refused(["export", str(dataset), "--format", "hdf5", "--out", str(precious), "--overwrite", "-q"], capsys,
             "not an HDF5 file written by physynth export")
    assert precious.read_bytes() == b"not physynth"
    folder = tmp_path / "csv"
    main(["export", str(dataset), "--format", "csv", "--out", str(folder), "-q"])
    main(["export", str(dataset), "--format", "csv", "--out", str(folder), "--overwrite", "-q"])  # its own: replaced
    (folder / "notes.txt").write_text("mine")
    _refused(["export", str(dataset), "--format", "csv", "--out", str(folder), "--overwrite", "-q"], capsys,
             "'notes.txt', which PhySynth did not write")
    assert (folder / "notes.txt").read_text() == "mine"


def test_never_the_input_or_the_current_folder(dataset, tmp_path, capsys, monkeypatch):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    before = sorted(p.name for p in copy.iterdir())
    _refused(["export", str(copy), "--format", "csv", "--out", str(copy), "--overwrite", "-q"], capsys,
             "is the input")
    assert sorted(p.name for p in copy.iterdir()) == before
    child = tmp_path / "parent" / "child"
    child.mkdir(parents=True)
    (child / "mine.txt").write_text("mine")
    monkeypatch.chdir(child)
    for out in ("..", "."):
        _refused(["export", str(copy), "--format", "hdf5", "--out", out, "--overwrite", "-q"], capsys,
                 "current folder")
    assert (child / "mine.txt").read_text() == "mine"


def test_csv_export_checks_the_dataset(dataset, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    meta["files"]["uwb.parquet"]["bytes"] += 1
    (copy / "dataset.json").write_text(json.dumps(meta))
    _refused(["export", str(copy), "--format", "csv", "--out", str(tmp_path / "c"), "-q"], capsys,
             "uwb.parquet")
    assert not (tmp_path / "c").exists()


def test_killed_export_leftovers_are_removed_with_a_warning(dataset, tmp_path):
    out = tmp_path / "c"
    dead = tmp_path / f".c.tmp-{2**22 + 12345}"  # a pid no process has here
    dead.mkdir()
    (dead / "uwb.csv").write_text("half")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        export_dataset(dataset, out, "csv")
    assert not dead.exists() and (out / "uwb.csv").is_file()
    assert any(issubclass(w.category, PhySynthWarning) and "interrupted run" in str(w.message) for w in caught)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".c.") and "lock" not in p.name]


def test_studies_refuse_a_users_folder_and_negative_seeds(tmp_path, capsys):
    users = tmp_path / "users"
    users.mkdir()
    (users / "scenario.yaml").write_text("mine")
    _refused(["study", "anchors", "-n", "2", "--seed", "1", "--no-figures", "--out", str(users), "-q"], capsys,
             "holds files and no table.json")
    _refused(["study", "tracking", "--methods", "ls", "--out", str(users), "-q"], capsys,
             "holds files and no results.json")
    assert (users / "scenario.yaml").read_text() == "mine"
    for argv in (["study", "anchors", "--seed", "-5", "--out", str(tmp_path / "a")],
                 ["study", "placement", "--seed", "-3", "--candidates", "x", "-k", "2", "--out", str(tmp_path / "p")],
                 ["study", "tracking", "--seed", "-1", "--out", str(tmp_path / "t")]):
        _refused(argv + ["-q"], capsys, "--seed")
    assert not os.path.exists(tmp_path / "a") and not os.path.exists(tmp_path / "t")


def test_unreachable_scheduler_leaves_nothing_to_resume(tmp_path, capsys):
    pytest.importorskip("distributed")
    out = tmp_path / "d"
    _refused(["generate", "-n", "2", "--seed", "1", "--scheduler", "tcp://127.0.0.1:1", "--out", str(out), "-q"],
             capsys, "cannot connect to the Dask scheduler")
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".d.partial")]
    main(["generate", "-n", "2", "--seed", "1", "--out", str(out), "-q"])  # no "unfinished run" in the way
    assert (out / "dataset.json").is_file()


def test_errors_name_the_options_not_the_parameters(dataset, tmp_path, capsys):
    _refused(["calibrate", str(dataset), "--layout-from", "7", "--out", str(tmp_path / "s.yaml"), "-q"], capsys,
             "--layout-from=7: there are 2 recordings")
    _refused(["calibrate", str(dataset), "--range-bias", "static", "--out", str(tmp_path / "s.yaml"), "-q"], capsys,
             "--range-bias static needs --static-sweeps")
    _refused(["calibrate", str(dataset), "--link-budget", "--out", str(tmp_path / "s.yaml"), "-q"], capsys,
             "--link-budget needs --static-sweeps")


def test_verify_checks_every_dataset(dataset, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(dataset, bad)
    data = bytearray((bad / "uwb.parquet").read_bytes())
    data[len(data) // 2] ^= 0x01
    (bad / "uwb.parquet").write_bytes(bytes(data))
    with pytest.raises(SystemExit) as e:
        main(["verify", str(bad), str(dataset)])
    out, err = capsys.readouterr()
    assert e.value.code == 2
    assert f"{dataset}: ok" in out  # the intact one after the damaged one is still checked
    assert "uwb.parquet" in err and "1 of 2 datasets failed verification" in err


def test_broad_import_of_a_folder_says_so(tmp_path, capsys):
    (tmp_path / "data_mat").mkdir()
    _refused(["import", "broad", str(tmp_path / "data_mat"), "--out", str(tmp_path / "o")], capsys,
             "is a folder; give a BROAD trial file")


def _write_recording(folder):
    """A tiny CSV recording (3 anchors, a tag walking east) for ``physynth import csv``."""
    folder.mkdir(parents=True)
    (folder / "anchors.csv").write_text("anchor_id,e_m,n_m,u_m\nA1,0,0,2\nA2,10,0,2\nA3,0,10,2\n")
    t = [round(0.1 * k, 1) for k in range(51)]
    (folder / "truth.csv").write_text("t_s,e_m,n_m,u_m\n" + "".join(f"{x},{x},5.0,1.0\n" for x in t))
    (folder / "uwb.csv").write_text("t_s,anchor_id,range_m\n" + "".join(
        f"{x},{a},{((x - e) ** 2 + (5 - n) ** 2 + 1) ** 0.5:.4f}\n"
        for x in t[1:-1] for a, e, n in (("A1", 0, 0), ("A2", 10, 0), ("A3", 0, 10))))
    return folder


def test_never_an_output_inside_an_input(dataset, tmp_path, capsys):
    """An output written inside an input dataset would make that dataset hold a file PhySynth did not
    write there, and refuse its later --overwrite: refused before any work."""
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    before = sorted(p.name for p in copy.iterdir())
    rec = _write_recording(tmp_path / "rec")
    rec_before = sorted(p.name for p in rec.iterdir())
    for argv in (["export", str(copy), "-f", "hdf5", "--out", str(copy / "x.h5")],
                 ["export", str(copy), "-f", "csv", "--out", str(copy / "sub" / "csv")],
                 ["calibrate", str(copy), "--out", str(copy / "x.yaml")],
                 ["calibrate", str(copy), "--out", str(tmp_path / "ok.yaml"), "--report", str(copy / "fit.json")],
                 ["validate", "--real", str(copy), "--synthetic", str(dataset), "--out", str(copy / "rep")],
                 ["study", "tracking", "--train", str(copy), "--test", str(dataset), "--methods", "ls",
                  "--out", str(copy / "st")],
                 ["import", "csv", str(rec), "--out", str(rec / "out")]):
        _refused([*argv, "-q"], capsys, "lies inside the input")
    assert sorted(p.name for p in copy.iterdir()) == before
    assert sorted(p.name for p in rec.iterdir()) == rec_before and not (tmp_path / "ok.yaml").exists()


def test_a_file_where_a_folder_goes_and_back_is_said_at_once(dataset, tmp_path, capsys):
    """Not "already exists (use --overwrite)", which --overwrite would then refuse anyway."""
    afile, folder = tmp_path / "afile", tmp_path / "folder"
    afile.write_text("mine")
    folder.mkdir()
    for argv in (["generate", "-n", "1", "--out", str(afile)],
                 ["export", str(dataset), "-f", "csv", "--out", str(afile)],
                 ["validate", "--real", str(dataset), "--synthetic", str(dataset), "--out", str(afile)]):
        _refused([*argv, "-q"], capsys, f"output {afile} is a file, not a folder")
    for argv in (["calibrate", str(dataset), "--out", str(folder)],
                 ["calibrate", str(dataset), "--out", str(tmp_path / "s.yaml"), "--report", str(folder)],
                 ["export", str(dataset), "-f", "hdf5", "--out", str(folder)]):
        _refused([*argv, "-q"], capsys, f"output {folder} is a folder, not a file")
    assert afile.read_text() == "mine" and not any(folder.iterdir())


def test_an_empty_output_is_used_and_a_foreign_one_is_refused_at_once(dataset, tmp_path, capsys):
    """An empty folder (an empty file for a file output) holds nothing to lose: it is used as if new. A
    folder of other files is refused at once, without advice to use --overwrite (which would refuse it)."""
    from physynth.io.safety import check_output

    empty_ds, empty_csv = tmp_path / "emptyout", tmp_path / "emptycsv"
    empty_ds.mkdir()
    empty_csv.mkdir()
    main(["generate", "-n", "1", "--seed", "1", "--out", str(empty_ds), "-q"])
    assert json.loads((empty_ds / "dataset.json").read_text())["n_traces"] == 1
    main(["export", str(dataset), "-f", "csv", "--out", str(empty_csv), "-q"])
    assert (empty_csv / "uwb.csv").is_file()
    empty_file = tmp_path / "site.yaml"
    empty_file.write_text("")
    assert check_output(empty_file, kind="scenario", overwrite=False) == empty_file.resolve()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.txt").write_text("mine")
    for argv, needle in ((["generate", "-n", "1", "--out", str(mine)], "not a PhySynth dataset"),
                         (["export", str(dataset), "-f", "csv", "--out", str(mine)], "not a CSV export")):
        with pytest.raises(SystemExit) as e:
            main([*argv, "-q"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and needle in err and err.count("\n") == 1, err
        assert "--overwrite" not in err and "already exists" not in err
    assert [p.name for p in mine.iterdir()] == ["thesis.txt"]


@pytest.mark.parametrize("study", [["anchors", "-n", "2", "--no-figures"],
                                   ["placement", "--candidates", "c.csv", "-k", "1", "--no-figures"],
                                   ["tracking", "--methods", "ls"]])
def test_studies_take_the_output_lock_generate_takes(tmp_path, capsys, study):
    """Issue 44: a study writing into a folder another run is writing is refused at once, as generate is."""
    from physynth.io.safety import OutputLock, lock_path

    out = tmp_path / "study"
    with OutputLock(out):
        _refused(["study", *study, "--seed", "1", "--out", str(out), "-q"], capsys,
                 "is being written by another physynth process")
    assert not out.exists() and not lock_path(out).exists()
