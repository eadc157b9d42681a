# Two commands for a new user; each sets itself up on a fresh machine.
#   make demo   create .venv, install what a run needs (no torch, no test tools), run
#               `rodctl simulate configs/default.yaml`
#   make test   create .venv, install torch and the extras `train` and `test`, run the test suite
# Where torch would come from PyPI with CUDA (gigabytes), take PyTorch's CPU build:
#   make test TORCH_INDEX=https://download.pytorch.org/whl/cpu      (docs/install.md)
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   := $(VENV)/.demo-installed
PLUGIN := $(VENV)/.plugin-installed
TORCH_INDEX ?=
TORCH_FROM  := $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX),)

.PHONY: demo test test-fast bench lint clean-venv

# The test set-up: torch first (TORCH_INDEX: from that index only, e.g. PyTorch's CPU build),
# then the project with the extras `train` (torch, already satisfied) and `test`.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet $(TORCH_FROM) torch==2.13.0
	$(BIN)/pip install --quiet -e ".[train,test]"
	touch $(STAMP) $(DEMO)

# What a run needs and nothing else: no torch, no test tools.
$(DEMO): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet -e .
	touch $(DEMO)

# The example plug-ins (examples/plugin/: a method; examples/plugin-kinds/: an event, a sink and
# an executor) are part of the test suite: the tests run them through the CLI and compare, as a
# user who installed them would.
$(PLUGIN): $(STAMP) examples/plugin/pyproject.toml examples/plugin-kinds/pyproject.toml
	$(BIN)/pip install --quiet -e examples/plugin -e examples/plugin-kinds
	touch $(PLUGIN)

demo: $(DEMO)
	$(BIN)/rodctl simulate configs/default.yaml

test: $(STAMP) $(PLUGIN)
	$(BIN)/python -m pytest -q

# The inner loop: every test but those marked `slow` (whole runs, compares, signals, Ray);
# `make test` (and CI) still runs them all (docs/development.md).
test-fast: $(STAMP) $(PLUGIN)
	$(BIN)/python -m pytest -q -m "not slow"

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

lint: $(STAMP)
	$(BIN)/ruff check rodctl tests benchmarks examples
	$(BIN)/ruff format --check rodctl tests benchmarks examples
	$(BIN)/lint-imports --no-cache
	$(BIN)/mypy

clean-venv:
	rm -rf $(VENV)
