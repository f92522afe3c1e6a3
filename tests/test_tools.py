"""The maintainer's tools (tools/README.md) run: each prints its help, and the ones that can run on a
tiny size in a second or two do, so that none rots unseen. The ones that need the shared real data or
minutes of work (leave-one-out, presets calibrated on real runs) are only started with ``--help``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[1] / "tools"
KEPT = sorted(p.stem for p in TOOLS.glob("*.py") if not p.name.startswith("_"))  # _x.py: helpers of the tools


def _run(*args: str, cwd: Path | None = None) -> str:
    out = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120, cwd=cwd)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_every_tool_is_in_the_readme():
    readme = (TOOLS / "README.md").read_text(encoding="utf-8")
    assert KEPT, "no tools found"
    missing = [t for t in KEPT if f"{t}.py" not in readme]
    assert not missing, f"tools/README.md does not name {missing}"


@pytest.mark.parametrize("tool", KEPT)
def test_tool_help(tool):
    assert "usage" in _run(str(TOOLS / f"{tool}.py"), "--help").lower()


def test_compare_traces_on_one_trace(tmp_path):
    dump = tmp_path / "a.npz"
    _run(str(TOOLS / "compare_traces.py"), "dump", str(dump), "-n", "1")
    assert "0 differ" in _run(str(TOOLS / "compare_traces.py"), "compare", str(dump), str(dump))


def test_preset_table_on_one_trace():
    assert "synth" in _run(str(TOOLS / "preset_table.py"), "cablecar-descending", "-n", "1")


def test_make_cablecar_presets_rebuilds_the_shipped_presets(tmp_path):
    from physynth.io.scenario_file import load_scenario

    _run(str(TOOLS / "make_cablecar_presets.py"), "--out", str(tmp_path))
    for name in ("cablecar-descending", "cablecar-ascending"):
        built, shipped = load_scenario(tmp_path / f"{name}.yaml"), load_scenario(name)
        a, b = built.model_dump(mode="json"), shipped.model_dump(mode="json")
        # the cable polynomial is solved numerically: its last digits depend on the machine's floating point
        np.testing.assert_allclose(a["path"].pop("coeffs_enu_m"), b["path"].pop("coeffs_enu_m"), rtol=1e-8, atol=1e-9)
        assert a == b, name


def test_ros2_types_check_finds_the_shipped_table_up_to_date():
    pytest.importorskip("rosbags")
    out = subprocess.run([sys.executable, str(TOOLS / "ros2_types.py"), "--check"], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "up to date" in out.stdout
