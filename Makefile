# Set-up and checks. Both targets create .venv and install what they need.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast lint docs bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/imuslam demo --out demo_out
	$(BIN)/imuslam study --quick --out demo_out/study

lint: $(STAMP)
	$(BIN)/ruff check src tests bench
	$(BIN)/ruff format --check src tests bench
	$(BIN)/mypy
	$(BIN)/lint-imports
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# The documentation site (mkdocs.yml, docs/) into site/; `.venv/bin/mkdocs serve` to browse it live.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# Both cores (pytest-xdist). --dist loadscope keeps each test module on one worker, so a module-scoped
# fixture (a VIO run, a real calibration, a 2D map) is computed once, not once per worker. Tests write only
# under tmp_path; numba writes its caches atomically (temporary file, then rename), so two workers
# compiling the same kernel do not collide; --warm-kernels has each worker compile one share of the
# kernel families first (tests/kernel_warmup.py), so no family is compiled by both workers at once.
# `make test` runs everything, slow Monte Carlo cases included.
PYTEST_XDIST := -n auto --dist loadscope --warm-kernels

test: lint
	$(BIN)/pytest -q $(PYTEST_XDIST)

# While developing: skip the long Monte Carlo cases (@pytest.mark.slow).
test-fast: $(STAMP)
	$(BIN)/pytest -q $(PYTEST_XDIST) -m "not slow"

# Every headline speed ratio against its anchor in the same run (about 10-15 min), written to
# bench/results.json and compared with bench/reference.json (fails when a row slipped beyond the noise).
# IMUTK_SRC=/path/to/imu_tk builds imu_tk's program for its rows; each bench/*.py also runs on its own.
bench: $(STAMP)
	$(BIN)/python bench/table.py
	$(BIN)/python bench/compare.py

clean:
	rm -rf $(VENV) demo_out .pytest_cache .mypy_cache .ruff_cache
