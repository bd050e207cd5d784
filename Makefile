# Two commands on a fresh machine:
#   make demo   - create .venv, install lunarmap, write the synthetic mission and print ground points
#   make test   - create .venv, install lunarmap with test extras, run the test suite
PYTHON ?= python3
# test processes (pytest-xdist): the suite's tests are independent; 2 = the machine's cores
TEST_WORKERS ?= 2
VENV   ?= .venv
BIN     = $(VENV)/bin

.PHONY: demo test bench fuzz install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --progress-bar on -e ".[test,bench]"
	touch $@

install: $(VENV)/.installed

demo: install
	$(BIN)/lunarmap run --example --output demo_output

test: install
	$(BIN)/python -m pytest -q -rs -n $(TEST_WORKERS)

bench: install
	$(BIN)/python bench/bench_camera.py

fuzz: install
	$(BIN)/python bench/fuzz.py

clean:
	rm -rf $(VENV) demo_output .pytest_cache
