# Two-command set-up: `make demo` and `make test` work on a fresh machine with python3.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
STAMP_DEV := $(VENV)/.installed-dev
STAMP_DOCS := $(VENV)/.installed-docs

.PHONY: demo test full bench docs browser rt clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e .
	touch $@

$(STAMP_DEV): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(STAMP) $@

$(STAMP_DOCS): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[docs]"
	touch $(STAMP) $@

# Headless Chromium for the report's browser test (Debian's package). Installed when absent
# and this is root (or sudo works); otherwise the test is skipped and says why.
browser:
	@if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then :; \
	elif ! command -v apt-get >/dev/null 2>&1; then echo "no apt-get: install chromium to run the report's browser test"; \
	else SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q \
	    --no-install-recommends chromium fonts-dejavu-core \
	  || echo "chromium could not be installed: the report's browser test will be skipped"; fi

# Sionna RT (the optional 3-D channel provider, extra `rt`) and Debian's LLVM library for its
# CPU back end. Installed when possible (apt-get as root or with sudo); otherwise the Sionna
# test is skipped and says why.
rt: $(STAMP_DEV)
	@$(BIN)/python -m pip install -q -e ".[rt]" || echo "sionna-rt could not be installed: the Sionna RT test will be skipped"
	@if ls /usr/lib/*/libLLVM-1*.so /usr/lib/llvm-1*/lib/libLLVM*.so >/dev/null 2>&1; then :; \
	elif ! command -v apt-get >/dev/null 2>&1; then echo "no apt-get: install libLLVM (e.g. libllvm19) to run the Sionna RT test"; \
	else SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo -n ); \
	  $$SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q \
	    --no-install-recommends libllvm19 \
	  || echo "libllvm19 could not be installed: the Sionna RT test will be skipped"; fi

demo: $(STAMP)
	$(BIN)/radioloc reproduce all --out out

test: $(STAMP_DEV) browser rt
	$(BIN)/python -m pytest -n 2 --dist loadfile --durations=20

docs: $(STAMP_DOCS)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict

full: $(STAMP)
	$(BIN)/radioloc reproduce all --full --workers 2 --out out-full

# `particles` (a benchmark peer) pins numpy<2 in its metadata although it runs on numpy 2;
# it is installed without its dependencies so that pip keeps the project's numpy.
bench: $(STAMP_DEV)
	$(BIN)/python -c "import particles" 2>/dev/null || $(BIN)/python -m pip install -q --no-deps particles
	$(BIN)/python benchmarks/collect.py

clean:
	rm -rf $(VENV) out out-full site .pytest_cache

# Long fuzz of `radioloc locate` and of the library's estimators and models (>= 10,000
# generated cases, each classified; the outcome counts of both workers are summed from
# out/fuzz-tally.jsonl and printed at the end). `make test` runs a fast profile.
.PHONY: fuzz
fuzz: $(STAMP_DEV)
	@mkdir -p out && rm -f out/fuzz-tally.jsonl
	RADIOLOC_FUZZ_PROFILE=long RADIOLOC_FUZZ_TALLY=out/fuzz-tally.jsonl \
	  $(BIN)/python -m pytest -n 2 -p no:cacheprovider tests/fuzz
