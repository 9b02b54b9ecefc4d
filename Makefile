# Two-command set-up: `make demo` and `make test` work on a fresh machine with python3.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
STAMP_DEV := $(VENV)/.installed-dev
STAMP_DOCS := $(VENV)/.installed-docs

.PHONY: demo test test-fast full bench docs system browser rt clean

# Packages install with uv (PyPI's `uv`, put into the venv first: on a fresh machine it
# installs the dev set in under a minute where pip took several); pip is the fallback.
# Every install takes its versions from the lock, constraints.txt (generated from
# pyproject.toml with every extra, for every platform and Python >= 3.11): `make lock`
# refreshes it after a change of pyproject.toml, or to move to newer releases.
UV_VERSION := 0.13.9
LOCK := constraints.txt
PIP := $(BIN)/python -m uv pip install -q --python $(BIN)/python -c $(LOCK)
PIP_FALLBACK := $(BIN)/python -m pip install -q -c $(LOCK)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q uv==$(UV_VERSION)

$(STAMP): pyproject.toml $(LOCK) | $(BIN)/python
	$(PIP) -e . || $(PIP_FALLBACK) -e .
	touch $@

$(STAMP_DEV): pyproject.toml $(LOCK) | $(BIN)/python
	$(PIP) -e ".[dev]" || $(PIP_FALLBACK) -e ".[dev]"
	touch $(STAMP) $@

$(STAMP_DOCS): pyproject.toml $(LOCK) | $(BIN)/python
	$(PIP) -e ".[docs]" || $(PIP_FALLBACK) -e ".[docs]"
	touch $(STAMP) $@

.PHONY: lock check-base
lock: | $(BIN)/python
	$(BIN)/python -m uv pip compile -q pyproject.toml --all-extras --universal \
	  --python-version 3.11 --custom-compile-command "make lock" -o $(LOCK)

# The base install as a new user gets it: a fresh venv with the package alone (built as a
# wheel, no extras, versions from the lock), then the README's first commands on examples/.
# A base import that pyproject.toml does not declare fails here. `.ci/run` runs it first.
BASE_VENV := .venv-base
check-base:
	@rm -rf $(BASE_VENV) out/check-base && mkdir -p out/check-base
	$(PYTHON) -m venv $(BASE_VENV)
	$(BASE_VENV)/bin/python -m pip install -q uv==$(UV_VERSION)
	$(BASE_VENV)/bin/python -m uv pip install -q --python $(BASE_VENV)/bin/python -c $(LOCK) . \
	  || $(BASE_VENV)/bin/python -m pip install -q -c $(LOCK) .
	@rm -rf build
	cd out/check-base && ../../$(BASE_VENV)/bin/radioloc --help > help.txt
	cd out/check-base && ../../$(BASE_VENV)/bin/radioloc locate ../../examples/measurements.csv \
	  --anchors ../../examples/anchors.csv --out estimates.csv --quiet
	cd out/check-base && ../../$(BASE_VENV)/bin/radioloc reproduce gn-multilateration --out .
	@echo "base install: radioloc --help, locate and reproduce gn-multilateration ran (out/check-base)"

# Debian packages the tests use: headless Chromium for the report's browser test, and LLVM's
# shared library for Sionna RT's CPU back end. Dr.Jit needs LLVM >= 19 (15 and 16 abort the
# process, 14 is refused: see LLVM_MIN_VERSION in radioloc/channel/sionna_rt.py), so libllvm19
# is installed whenever the newest libLLVM present is older, whatever else is there. One
# apt-get call for whichever is absent, when this is root (or sudo works); otherwise the tests
# that need them are skipped and say why.
LLVM_MIN := 19
LLVM_NEWEST := $(shell ls /usr/lib/*/libLLVM* /usr/lib/llvm-*/lib/libLLVM*.so* 2>/dev/null \
                 | grep -oE 'libLLVM[-.](so[.])?[0-9]+' | grep -oE '[0-9]+$$' | sort -n | tail -1)
SYSTEM_PKGS = $(shell command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || echo chromium fonts-dejavu-core) \
              $(shell [ "$(or $(LLVM_NEWEST),0)" -ge $(LLVM_MIN) ] || echo libllvm$(LLVM_MIN)) \
              $(shell command -v mosquitto >/dev/null 2>&1 || [ -x /usr/sbin/mosquitto ] || echo mosquitto)
system:
	@if [ -z "$(strip $(SYSTEM_PKGS))" ]; then :; \
	elif ! command -v apt-get >/dev/null 2>&1; then echo "no apt-get: install $(strip $(SYSTEM_PKGS)) to run the browser / Sionna RT / MQTT tests"; \
	else SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo -n ); \
	  $$SUDO apt-get update -q && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -q \
	    --no-install-recommends $(SYSTEM_PKGS) \
	  || echo "$(strip $(SYSTEM_PKGS)) could not be installed: the browser / Sionna RT / MQTT tests will be skipped"; fi

browser: system

# Sionna RT (the optional 3-D channel provider, extra `rt`); its LLVM library comes from
# `system`. Installed when possible; otherwise the Sionna test is skipped and says why.
rt: $(STAMP_DEV)
	@$(PIP) -e ".[rt]" || $(PIP_FALLBACK) -e ".[rt]" || echo "sionna-rt could not be installed: the Sionna RT test will be skipped"

# numba's parallel kernels run on OpenMP threads, which spin while they wait for each other;
# where more threads than cores are busy (two test workers, a benchmark beside its peer) the
# spinning takes the CPU the working threads need. The targets that run kernels ask OpenMP
# to wait passively (the library itself changes no environment).
export OMP_WAIT_POLICY ?= passive

demo: $(STAMP)
	$(BIN)/radioloc reproduce all --out out

# The Debian packages and the Python ones install side by side (two jobs); the estimators'
# kernels compile into numba's cache in two processes (tests/precompile.py: otherwise both
# test workers compile the larger ones at once); then the tests run. Every test has a time
# limit (pyproject.toml), and a worker that crashes or times out is replaced: the test fails,
# the run goes on. `--dist worksteal` hands out single tests (a crashed worker's file is not
# sent again to the next worker, as `loadfile` does).
test:
	@$(MAKE) --no-print-directory -j2 system rt
	$(BIN)/python tests/precompile.py
	$(BIN)/python -m pytest -n 2 --dist worksteal --durations=20 -m "not docs_current"

# The fast tier for the development loop: everything but the `slow` modules (tests/conftest.py).
test-fast: $(STAMP_DEV)
	$(BIN)/python -m pytest -n 2 --dist worksteal -m "not slow"

# The generated pages are checked against their scripts at full size first (skipped
# without RADIOLOC_DATA), then the site is built.
docs: $(STAMP_DEV) $(STAMP_DOCS)
	$(BIN)/python -m pytest -n 2 -m docs_current tests/test_datasets_tutorials.py
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict

full: $(STAMP)
	$(BIN)/radioloc reproduce all --full --workers 2 --out out-full

# `particles` (a benchmark peer) pins numpy<2 in its metadata although it runs on numpy 2;
# it is installed without its dependencies so that pip keeps the project's numpy.
bench: $(STAMP_DEV)
	$(BIN)/python -c "import particles" 2>/dev/null || $(PIP) --no-deps particles==0.4 || $(BIN)/python -m pip install -q --no-deps particles==0.4
	$(BIN)/python benchmarks/collect.py

clean:
	rm -rf $(VENV) $(BASE_VENV) out out-full site .pytest_cache

# Long fuzz of `radioloc locate` and of the library's estimators and models (>= 10,000
# generated cases, each classified; the outcome counts of both workers are summed from
# out/fuzz-tally.jsonl and printed at the end). `make test` runs a fast profile. A test of
# the long profile runs 1200 cases, longer than the suite's 600 s limit a test: an hour here.
.PHONY: fuzz
fuzz: $(STAMP_DEV)
	@mkdir -p out && rm -f out/fuzz-tally.jsonl
	RADIOLOC_FUZZ_PROFILE=long RADIOLOC_FUZZ_TALLY=out/fuzz-tally.jsonl \
	  $(BIN)/python -m pytest -n 2 -p no:cacheprovider --timeout 3600 tests/fuzz
