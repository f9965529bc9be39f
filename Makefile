# The two commands of the README. Both set up everything on a fresh machine (Python 3.11,
# cargo, PyPI and crates.io reachable) and are quick when nothing changed.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
# Anything that changes the extension triggers a rebuild.
RUST_SOURCES := $(shell find crates -name '*.rs' -o -name Cargo.toml) Cargo.toml Cargo.lock
PY_SOURCES := $(shell find python -type f -not -name '*.so' -not -path '*/__pycache__/*') pyproject.toml

.PHONY: demo test test-rust test-python bench build clean

demo: $(VENV)/.built
	$(VENV)/bin/tightscan demo

test: $(VENV)/.built
	cargo clippy --workspace --all-targets --quiet -- -D warnings
	cargo test --workspace --exclude tightscan-python --all-targets
	$(PY) -m pytest
	$(PY) -m mypy python/tightscan
	$(PY) -m mypy.stubtest tightscan._core --mypy-config-file pyproject.toml --allowlist tests/stubtest-allowlist.txt

$(VENV)/.deps: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "maturin>=1.9,<2" pyarrow numpy rich "scipy>=1.11" "statsmodels>=0.14" "pytest>=8" "hypothesis>=6.100" "polars>=1.0" "mypy>=1.10" "matplotlib>=3.8"
	# scan engines and a local S3 server for tests/test_engines.py and tests/test_sources.py (issue 13)
	$(PY) -m pip install --quiet "dask[distributed]>=2024.1" "pandas>=2.0" "ray[data]>=2.9" "moto[server]>=5"
	touch $@

$(VENV)/.built: $(VENV)/.deps $(RUST_SOURCES) $(PY_SOURCES)
	VIRTUAL_ENV=$(abspath $(VENV)) PATH=$(abspath $(VENV))/bin:$$PATH $(VENV)/bin/maturin develop --release --quiet
	touch $@

build: $(VENV)/.built

bench: $(VENV)/.built
	$(PY) -m pip install --quiet ".[bench]" --no-deps 2>/dev/null || true
	$(PY) -m pip install --quiet ruptures statsmodels river scipy matplotlib pandas
	$(PY) benches/bench_cusum.py
	cargo bench -p tightscan-benches

clean:
	rm -rf $(VENV) target out
