"""Progress without a terminal: a log file or a pipe gets sparse plain lines, not bars or nothing."""

from __future__ import annotations

from physynth.cli import _common
from physynth.cli._common import progress_bar, status_lines


def _lines(capsys) -> list[str]:
    return capsys.readouterr().err.splitlines()


def test_status_lines_print_each_stage_once_per_interval(capsys, monkeypatch):
    monkeypatch.setattr(_common, "LOG_INTERVAL_S", 3600.0)
    with status_lines("study") as say:
        for m in ("SYNTH_PHY pre-train: epoch 1/3", "SYNTH_PHY pre-train: epoch 2/3", "ls: running on the test run",
                  "SYNTH_PHY pre-train: epoch 3/3"):
            say(m)
    assert _lines(capsys) == ["  - SYNTH_PHY pre-train: epoch 1/3", "  - ls: running on the test run"]
    monkeypatch.setattr(_common, "LOG_INTERVAL_S", 0.0)  # every message is due
    long = "A: epoch 2/2, " + "training RMSE 0.618 m " * 6  # past 80 columns: one line all the same
    with status_lines("study") as say:
        say("A: epoch 1/2")
        say(long)
    assert _lines(capsys) == ["  - A: epoch 1/2", "  - " + long]


def test_progress_bar_logs_only_steps_longer_than_the_interval(capsys, monkeypatch):
    monkeypatch.setattr(_common, "LOG_INTERVAL_S", 3600.0)
    with progress_bar() as progress:
        progress("generating", 1, 4)
        progress("generating", 4, 4)
    assert _lines(capsys) == []  # a short step leaves nothing, as before
    monkeypatch.setattr(_common, "LOG_INTERVAL_S", 0.0)
    with progress_bar() as progress:
        progress("generating", 1, 4)
        progress("generating", 4, 4)
        progress("a step without a count")
    lines = _lines(capsys)
    assert [ln.split(" after ")[0] for ln in lines[:2]] == ["  - generating: 1/4 (25 %)", "  - generating: 4/4 (100 %)"]
    assert lines[2] == "  - a step without a count" and len(lines) == 3


def test_tracking_study_log_names_its_steps(tmp_path, capsys):
    """The study used to print nothing at all to a log until its table (a spinner, drawn only on a terminal)."""
    from physynth.cli import main
    from physynth.generate import generate_trace
    from physynth.io import write_dataset
    from physynth.io.scenario_file import load_scenario

    scn = load_scenario("walk-hanyang")
    runs = [generate_trace(scn, i, 7) for i in range(3)]
    train, test = write_dataset(tmp_path / "train", runs[:2]), write_dataset(tmp_path / "test", runs[2:])
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls,ekf",
          "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert "  - estimating the UWB time lag on the training runs" in err
    assert "  - ekf: running on the test run" in err
    main(["study", "tracking", "--train", str(train), "--test", str(test), "--methods", "ls",
          "--out", str(tmp_path / "quiet"), "-q"])
    assert capsys.readouterr().err == ""  # --quiet stays silent
