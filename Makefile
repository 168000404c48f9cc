# Two entry points: `make test` (installs everything into .venv, then runs the suite)
# and `make demo` (installs the package with matplotlib, then runs the main job on the shipped
# default problem: progress on the terminal, the list of outputs and the next step at the end).
# `make gpu-check` runs the device check (docs/gpu.md) with .venv's Python where there is one, else
# python3 (a CUDA machine without network installs from carried wheels); pass options in ARGS,
# e.g. `make gpu-check ARGS="--device cpu --tiny"`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: test demo install clean gpu-check

DEMO_STAMP := $(VENV)/.installed-demo

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -e ".[test]"
	touch $(STAMP) $(DEMO_STAMP)

# the demo needs the package and matplotlib for its figures, not the test tools
$(DEMO_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -e ".[figures]"
	touch $(DEMO_STAMP)

install: $(STAMP)

# the suite's files shared out over a pytest process per core (pytest-xdist; at most 4, tests/conftest.py),
# each file's tests in one process, as its module fixtures are; `pytest -q` alone runs them one by one.
# -rs lists every skipped test with its reason (no GPU, no display, ...); --durations=5 the slowest.
# About 13 minutes on a quiet 2-core machine, much longer on a busy one (README, *How long things take*).
test: $(STAMP)
	@echo "make test: the whole suite, about 13 minutes on 2 free cores (longer on a busy machine)"
	$(BIN)/python -m pytest -q -rs --durations=5 -n auto --dist loadfile

demo: $(DEMO_STAMP)
	$(BIN)/warp-shape design

gpu-check:
	PYTHON=$(if $(wildcard $(BIN)/python),$(BIN)/python,$(PYTHON)) bash scripts/gpu_check.sh $(ARGS)

clean:
	rm -rf $(VENV) build *.egg-info out out.partial .out.lock
