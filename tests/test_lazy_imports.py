"""Start-up: the generation path generates (and reports) its first trace before it imports pyarrow.

Each check runs in a fresh interpreter, since this test process has long imported pyarrow.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import physynth

_SRC = str(Path(physynth.__file__).parents[1])  # the tree under test, also in the child process


def _child(code: str) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([_SRC, os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


GENERATE_IN_MEMORY = """
import json, sys
import physynth.cli.generate, physynth.parallel, physynth.workflows
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
trace = generate_trace(compile_scenario(load_scenario("cablecar-descending")), 0, 1)
print(json.dumps({"rows": int(trace.truth.t_s.size), "pyarrow": "pyarrow" in sys.modules}))
"""


def test_generation_path_does_not_import_pyarrow():
    got = _child(GENERATE_IN_MEMORY)
    assert got["rows"] > 0
    assert got["pyarrow"] is False


GENERATE_DATASET = """
import json, sys
from physynth.io.dataset import read_dataset
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset
seen = []
def progress(message, done=None, total=None):
    if done:
        seen.append("pyarrow" in sys.modules)
out = sys.argv[1]
generate_dataset(load_scenario("cablecar-descending"), 2, out, seed=1, progress=progress)
print(json.dumps({"seen": seen, "read": len(read_dataset(out))}))
"""


def test_first_trace_is_reported_before_pyarrow_is_imported(tmp_path):
    got = _child(GENERATE_DATASET.replace("sys.argv[1]", repr(str(tmp_path / "d"))))
    assert len(got["seen"]) == 2 and got["seen"][0] is False  # pyarrow comes with the first conversion
    assert got["read"] == 2


EXPORT = """
import json, sys
from physynth.cli import main
sys.argv = ["physynth", "export", sys.argv[1], "-f", FORMAT, "-o", sys.argv[2], "-q"]
try:
    main()
except SystemExit as exc:
    assert not exc.code, exc.code
print(json.dumps({m: m in sys.modules for m in ("physynth.generate", "physynth.scenario", "physynth.models.uwb",
                                                 "pyarrow.compute")}))
"""


@pytest.mark.parametrize("fmt", ["csv", "hdf5", "rosbag2"])
def test_an_export_starts_without_the_generator_and_the_scenario_model(tmp_path, fmt):
    """An export needs neither (they took 65 ms of its start, on a 20-trace export of 0.8 s), nor
    pyarrow.compute (30 ms): the readers take nulls and dictionaries from the columns' buffers."""
    from physynth.workflows import generate_dataset

    pytest.importorskip({"csv": "polars", "hdf5": "h5py", "rosbag2": "rosbags"}[fmt])
    ds, _ = generate_dataset("cablecar-descending", 2, tmp_path / "ds", seed=1)
    code = EXPORT.replace("sys.argv[1]", repr(str(ds))).replace("sys.argv[2]", repr(str(tmp_path / "out")))
    got = _child(code.replace("FORMAT", repr(fmt)))
    assert (tmp_path / "out").exists()
    assert not any(got.values()), got
