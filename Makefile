# Every target creates .venv when it is missing and (re)installs the project when
# pyproject.toml changed.  The quick start in README.md is `make demo` and `make test`.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
KERNELS := $(VENV)/.kernels

.PHONY: demo test lint browser bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[all]'
	touch $(STAMP)

# numba's kernels, compiled once ahead of use (firmware_sim's plant runs them in real time).
# numba checks a cached kernel against its own file only, and the kernels inline each other's
# functions across these files: a change to any of them compiles them all again.
KERNEL_SOURCES := $(addprefix feeder/plant/,kernels.py planar_arrays.py limit_surface_kernels.py \
	slip_kernels.py planar_kernels.py)
$(KERNELS): $(STAMP) $(KERNEL_SOURCES)
	rm -f feeder/plant/__pycache__/*.nbi feeder/plant/__pycache__/*.nbc
	$(BIN)/python -m feeder.plant.warm_kernels
	touch $(KERNELS)

demo: $(KERNELS)
	$(BIN)/feeder demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

test: lint browser $(KERNELS)
	$(BIN)/python -m pytest

# the console's browser tests drive Debian's Chromium: installed here where this can (root with
# apt-get); elsewhere they skip, saying why
browser:
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
	    && echo "installing Debian's chromium for the browser tests" \
	    && { apt-get update -qq && apt-get install -y -qq chromium; } >/dev/null 2>&1; } \
	    || echo "chromium not installed: the browser tests will skip"

bench: $(KERNELS)
	$(BIN)/python benchmarks/run.py

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache
