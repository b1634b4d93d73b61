# DepthGuard: the two commands of the quick start are `make demo` and `make test`.
# Both create .venv/ on first use, reuse it afterwards and rebuild it when pyproject.toml changes.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# the tests run in 2 worker processes, one test file per worker at a time (pytest-xdist): the CI machine has
# 2 cores, and the numba kernels then compile in both at once; `make test WORKERS=0` runs them in one process
WORKERS ?= 2
PYTEST_PAR := $(if $(filter 0,$(WORKERS)),,-n $(WORKERS) --dist loadfile)

.PHONY: venv demo test test-quick test-random lint bench clean

$(STAMP): pyproject.toml
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[all]"
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/depthguard demo

# every extra is installed here, so a skipped test is a failure (tests/conftest.py; listed skips excepted)
test: $(STAMP)
	DEPTHGUARD_REQUIRE_EXTRAS=1 $(BIN)/python -m pytest -q $(PYTEST_PAR)

# the property tests with fresh random seeds and 5x their examples (CI runs them derandomized)
test-random: $(STAMP)
	DEPTHGUARD_HYPOTHESIS=random $(BIN)/python -m pytest -q $(PYTEST_PAR) -m "not slow"

test-quick: $(STAMP)
	DEPTHGUARD_REQUIRE_EXTRAS=1 $(BIN)/python -m pytest -q $(PYTEST_PAR) -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check src tests examples

bench: $(STAMP)
	$(BIN)/depthguard bench distance --json

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info $${XDG_CACHE_HOME:-$$HOME/.cache}/depthguard/numba
