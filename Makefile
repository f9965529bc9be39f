# The two commands of the README. Both set up everything on a fresh machine (Python 3.11,
# cargo, PyPI and crates.io reachable) and are quick when nothing changed.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
# Anything that changes the extension triggers a rebuild.
RUST_SOURCES := $(shell find crates -path '*/fuzz' -prune -o \( -name '*.rs' -o -name Cargo.toml \) -print) Cargo.toml Cargo.lock
PY_SOURCES := $(shell find python -type f -not -name '*.so' -not -path '*/__pycache__/*') pyproject.toml

.PHONY: demo test test-rust test-python bench build clean fuzz-smoke browser

demo: $(VENV)/.built
	$(VENV)/bin/tightscan demo

test: $(VENV)/.built browser
	cargo clippy --workspace --all-targets --quiet -- -D warnings
	cargo test --workspace --exclude tightscan-python --all-targets
	$(PY) -m pytest
	$(PY) -m mypy python/tightscan
	$(PY) -m mypy.stubtest tightscan._core --mypy-config-file pyproject.toml --allowlist tests/stubtest-allowlist.txt
	$(MAKE) --no-print-directory fuzz-smoke

# tests/test_report.py renders the HTML report in Debian's chromium (headless). Installed here
# when missing and apt-get can (root, Debian); elsewhere that test is skipped and says why.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  { apt-get install -y --no-install-recommends chromium >/dev/null 2>&1 || \
	    { apt-get update >/dev/null 2>&1 && apt-get install -y --no-install-recommends chromium >/dev/null 2>&1; }; } || \
	  echo "browser SKIPPED: chromium is not installed and apt-get could not install it; tests/test_report.py's browser test will skip"

# A short libFuzzer run of the engine's entry point (docs/fuzzing.md). A crash fails the tests.
# A machine that cannot build the fuzzer (no rustup nightly, no cargo-fuzz and no network to
# install them) skips it with a warning: that is not a finding. On a fresh machine installing
# cargo-fuzz takes about a minute, the first build of the target a few more. It starts from the
# committed seeds only (a fresh corpus each time), so that a long local corpus does not make
# the smoke run long.
FUZZ_CRATE := crates/tightscan-core
FUZZ_SECONDS ?= 15
fuzz-smoke:
	@rustup run nightly rustc --version >/dev/null 2>&1 || rustup toolchain install nightly --profile minimal || true
	@cargo fuzz --version >/dev/null 2>&1 || cargo install cargo-fuzz --locked || true
	@if ! rustup run nightly rustc --version >/dev/null 2>&1 || ! cargo fuzz --version >/dev/null 2>&1; then \
	  echo "fuzz-smoke SKIPPED: needs rustup's nightly toolchain and cargo-fuzz, which could not be installed"; exit 0; fi; \
	cd $(FUZZ_CRATE) && if ! cargo +nightly fuzz build detect >fuzz/build.log 2>&1; then \
	  tail -20 fuzz/build.log; echo "fuzz-smoke SKIPPED: the fuzz target does not build here (fuzz/build.log)"; exit 0; fi; \
	rm -rf fuzz/corpus/smoke && mkdir -p fuzz/corpus/smoke fuzz/seeds/detect && \
	RAYON_NUM_THREADS=1 cargo +nightly fuzz run detect fuzz/corpus/smoke fuzz/seeds/detect -- \
	  -max_total_time=$(FUZZ_SECONDS) -runs=500000 -timeout=60 -rss_limit_mb=2048 -print_final_stats=1

$(VENV)/.deps: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "maturin>=1.9,<2" pyarrow numpy rich "scipy>=1.11" "statsmodels>=0.14" "pytest>=8" "hypothesis>=6.100" "polars>=1.0" "mypy>=1.10" "matplotlib>=3.8"
	# scan engines and a local S3 server for tests/test_engines.py and tests/test_sources.py (issue 13)
	$(PY) -m pip install --quiet "dask[distributed]>=2024.1" "pandas>=2.0" "ray[data]>=2.9" "moto[server]>=5"
	# tests/test_frames.py: duckdb relations in, pandas in and out (pandas also comes with statsmodels)
	$(PY) -m pip install --quiet "duckdb>=1.1" "pandas>=2.2"
	# tests/test_detection_quality_bench.py runs the detection-quality benchmark's peers (issue 11 item 5)
	$(PY) -m pip install --quiet "ruptures>=1.1" "river>=0.21"
	# mypy sees pandas' types (detect_batch's overloads: pandas in, pandas out; tests/test_typing.py)
	$(PY) -m pip install --quiet pandas-stubs
	# tightscan config --show writes TOML with tomli-w (a core dependency in pyproject.toml; issue 14)
	$(PY) -m pip install --quiet "tomli-w>=1.0"
	# tightscan report (issue 14): its Jinja2 templates; tests/test_report.py reads the browser's screenshot with Pillow
	$(PY) -m pip install --quiet "jinja2>=3.1" "pillow>=10"
	touch $@

$(VENV)/.built: $(VENV)/.deps $(RUST_SOURCES) $(PY_SOURCES)
	VIRTUAL_ENV=$(abspath $(VENV)) PATH=$(abspath $(VENV))/bin:$$PATH $(VENV)/bin/maturin develop --release --quiet
	touch $@

build: $(VENV)/.built

bench: $(VENV)/.built
	$(PY) -m pip install --quiet ".[bench]" --no-deps 2>/dev/null || true
	$(PY) -m pip install --quiet ruptures statsmodels river scipy matplotlib pandas
	cargo bench -p tightscan-benches
	$(PY) benches/bench_cusum.py
	# issue 15: simulate and scan end to end (peak RSS, scan / pyarrow read), then ONE table of
	# every figure beside its goal, which also regenerates the README's performance table
	$(PY) benches/plant.py --n 20000
	$(PY) benches/perf_table.py --readme README.md

clean:
	rm -rf $(VENV) target out
