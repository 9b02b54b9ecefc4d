# Two-command set-up: `make demo` and `make test` work on a fresh machine with python3.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
STAMP_DEV := $(VENV)/.installed-dev

.PHONY: demo test full bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e .
	touch $@

$(STAMP_DEV): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(STAMP) $@

demo: $(STAMP)
	$(BIN)/radioloc reproduce all --out out

test: $(STAMP_DEV)
	$(BIN)/python -m pytest -n 2

full: $(STAMP)
	$(BIN)/radioloc reproduce all --full --workers 2 --out out-full

bench: $(STAMP_DEV)
	for f in benchmarks/bench_*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) out out-full .pytest_cache

# Long fuzz of `radioloc locate` (>= 10,000 generated cases; `make test` runs a fast profile).
.PHONY: fuzz
fuzz: $(STAMP_DEV)
	RADIOLOC_FUZZ_PROFILE=long $(BIN)/python -m pytest -n 2 -p no:cacheprovider tests/fuzz
