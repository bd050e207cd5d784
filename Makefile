# Two commands on a fresh machine:
#   make demo   - create .venv, install lunarmap, write the synthetic mission and print ground points
#   make test   - create .venv, install lunarmap with test extras, run the test suite
PYTHON ?= python3
# test processes (pytest-xdist): the suite's tests are independent; 2 = the machine's cores
TEST_WORKERS ?= 2
VENV   ?= .venv
BIN     = $(VENV)/bin

.PHONY: demo test bench fuzz install clean wheel-check docs lint

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

# sdist + wheel, the wheel installed into a fresh venv outside the source tree, the CLI run there
# (minutes: not part of .ci/run; see .ci/wheel_check.py)
$(VENV)/.installed-dev: pyproject.toml | $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e ".[test,bench,docs,dev]"
	touch $@

# lint + import order (ruff) and type checking (mypy) of the library; configuration, the reasons for
# ruff's ignores and mypy's per-library overrides in pyproject.toml
lint: install
	$(BIN)/python -m ruff --version >/dev/null 2>&1 || $(BIN)/python -m pip install --quiet "ruff>=0.6,<0.18"
	$(BIN)/python -m mypy --version >/dev/null 2>&1 || $(BIN)/python -m pip install --quiet "mypy>=1.10"
	$(BIN)/python -m ruff check lunarmap
	$(BIN)/python -m mypy lunarmap

# the documentation site: warnings (broken references, docstring errors, a failing notebook cell) fail it
docs: $(VENV)/.installed-dev
	rm -rf docs/_build docs/jupyter_execute
	$(BIN)/sphinx-build -W --keep-going -n -b html docs docs/_build/html
	@echo "open docs/_build/html/index.html"

wheel-check: $(VENV)/.installed-dev
	$(BIN)/python .ci/wheel_check.py

clean:
	rm -rf $(VENV) demo_output .pytest_cache dist build docs/_build
