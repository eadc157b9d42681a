# Two commands for a new user; each sets itself up on a fresh machine.
#   make demo   create .venv, install, run `rodctl simulate configs/default.yaml`
#   make test   create .venv, install, run the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PLUGIN := $(VENV)/.plugin-installed

.PHONY: demo test bench lint clean-venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# The CPU build of torch first: an unpinned torch would pull gigabytes of CUDA packages.
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[test]"
	touch $(STAMP)

# The example plug-in (examples/plugin/) is part of the test suite: the tests run it through
# the CLI and compare, as a user who installed it would.
$(PLUGIN): $(STAMP) examples/plugin/pyproject.toml
	$(BIN)/pip install --quiet -e examples/plugin
	touch $(PLUGIN)

demo: $(STAMP)
	$(BIN)/rodctl simulate configs/default.yaml

test: $(STAMP) $(PLUGIN)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

lint: $(STAMP)
	$(BIN)/ruff check rodctl tests benchmarks examples
	$(BIN)/ruff format --check rodctl tests benchmarks examples

clean-venv:
	rm -rf $(VENV)
