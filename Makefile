# Two commands do all the set-up on a fresh machine (Python >= 3.10 with venv):
#   make run    create .venv, install PhySynth (with matplotlib for figures), generate 20 traces of the default preset, print their metrics
#   make test   create .venv, install PhySynth with its test extras, run the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin

.PHONY: run test bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# An editable install leaves src/ uncompiled; where PYTHONDONTWRITEBYTECODE is set, every command would
# then recompile PhySynth's modules (about 65 ms of start-up), so compile them once here.
run: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[report]'
	$(BIN)/python -m compileall -q src
	$(BIN)/physynth generate --scenario cablecar-descending -n 20 --seed 2026 --out runs/default --overwrite
	$(BIN)/physynth inspect runs/default

test: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[test]'
	$(BIN)/python -m compileall -q src
	$(BIN)/python -m pytest -q -n auto --dist loadfile

bench: $(BIN)/python
	$(BIN)/pip install --quiet -e '.[test,bench]'
	$(BIN)/python -m compileall -q src
	$(BIN)/physynth bench
	$(BIN)/python benchmarks/bench_imu_vs_imusim.py

clean:
	rm -rf $(VENV) runs build *.egg-info src/*.egg-info
