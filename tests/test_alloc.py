"""The glibc allocator tuning (physynth._alloc): opt-out, no-op off glibc, once per process, same values."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from physynth import _alloc
from physynth.generate import compile_scenario
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


@pytest.fixture
def fresh(monkeypatch):
    """A process state in which the tuning has not been tried yet (restored afterwards)."""
    monkeypatch.setitem(_alloc._state, "applied", None)
    calls: list[tuple[int, int]] = []

    def fake_mallopt(param: int, value: int) -> int:
        calls.append((param, value))
        return 1

    monkeypatch.setattr(_alloc, "_load_mallopt", lambda: fake_mallopt)
    monkeypatch.setattr(_alloc, "is_glibc", lambda: True)
    return calls


@pytest.mark.parametrize("value", ["0", "false", "OFF", " no "])
def test_opt_out_calls_nothing(fresh, monkeypatch, value):
    monkeypatch.setenv(_alloc.ENV_VAR, value)
    monkeypatch.setattr(_alloc, "_load_mallopt", lambda: pytest.fail("mallopt looked up despite the opt-out"))
    compile_scenario(load_scenario("cablecar-descending"))
    assert _alloc.tune_allocator() is False
    assert fresh == []


def test_no_op_off_glibc(fresh, monkeypatch):
    monkeypatch.delenv(_alloc.ENV_VAR, raising=False)
    monkeypatch.setattr(_alloc, "is_glibc", lambda: False)
    monkeypatch.setattr(_alloc, "_load_mallopt", lambda: pytest.fail("mallopt looked up off glibc"))
    assert _alloc.tune_allocator() is False


def test_set_once_per_process(fresh, monkeypatch):
    monkeypatch.setenv(_alloc.ENV_VAR, "1")
    compile_scenario(load_scenario("cablecar-descending"))
    compile_scenario(load_scenario("cablecar-ascending"))
    assert _alloc.tune_allocator() is True
    assert fresh == [(_alloc.M_MMAP_THRESHOLD, 4 << 20), (_alloc.M_TRIM_THRESHOLD, 32 << 20)]


_CHILD = """
import hashlib, sys
import numpy as np
from physynth import _alloc
from physynth.constants import IMU_BODY_FRAME, IMU_FRAME
from physynth.generate import compile_scenario, generate_trace
from physynth.io.scenario_file import load_scenario
scn = load_scenario("cablecar-descending").model_copy(update={"imu_frames": [IMU_FRAME, IMU_BODY_FRAME]})
cs = compile_scenario(scn)
h = hashlib.sha256()
for i in range(3):
    tr = generate_trace(cs, i, 7)
    for a in (tr.truth.pos_enu_m, tr.truth.quat_wxyz, tr.imu.acc_mps2, tr.imu.acc_body_mps2,
              tr.imu.gyro_body_radps, tr.uwb.range_m, tr.uwb.reason):
        h.update(np.ascontiguousarray(a).tobytes())
print(_alloc.tune_allocator(), h.hexdigest())  # tried once already: what compile_scenario did
"""


def _child(env_value: str) -> tuple[str, str]:
    env = {**os.environ, _alloc.ENV_VAR: env_value}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(_alloc.__file__).parents[1]), env.get("PYTHONPATH", "")])
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, check=True)
    applied, digest = out.stdout.split()
    return applied, digest


def test_same_traces_with_and_without_tuning():
    applied_on, on = _child("1")
    applied_off, off = _child("0")
    assert applied_off == "False"
    if _alloc.is_glibc():
        assert applied_on == "True"
    assert on == off


_EXPORT_CHILD = """
import resource, shutil, sys
from pathlib import Path
from physynth.io.export import export_dataset
out = Path(sys.argv[2])
for _ in range(3):  # the third export's page faults: after the first has warmed imports and caches
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    export_dataset(Path(sys.argv[1]), out, "rosbag2")
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not _alloc.is_glibc(), reason="the tuning applies on glibc Linux only")
@pytest.mark.skipif(importlib.util.find_spec("rosbags") is None, reason="needs rosbags (physynth[ros])")
def test_export_parts_tune_the_allocator_in_a_dask_like_worker(tmp_path):
    """Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536 (distributed's
    ``nanny.pre-spawn-environ``): glibc then hands freed heap back after every bag and faults it in again
    (2.8 million page faults for 1,000 traces). An export part sets the thresholds first, as generation
    does: measured 12,600 against 540 page faults for five traces."""
    ds, _ = generate_dataset(load_scenario("cablecar-descending"), 5, tmp_path / "ds", seed=3)
    faults = {}
    for value in ("0", "1"):
        env = {**os.environ, _alloc.ENV_VAR: value, "MALLOC_TRIM_THRESHOLD_": "65536"}
        env["PYTHONPATH"] = os.pathsep.join([str(Path(_alloc.__file__).parents[1]), env.get("PYTHONPATH", "")])
        out = subprocess.run([sys.executable, "-c", _EXPORT_CHILD, str(ds), str(tmp_path / f"bags{value}")],
                             env=env, capture_output=True, text=True, check=True)
        faults[value] = int(out.stdout.split()[-1])
    assert faults["1"] * 4 < faults["0"], faults
