# Two entry points: `make test` (installs everything into .venv, then runs the suite)
# and `make demo` (runs the main job on the shipped default problem).
# `make gpu-check` runs the device check (docs/gpu.md) with .venv's Python where there is one, else
# python3 (a CUDA machine without network installs from carried wheels); pass options in ARGS,
# e.g. `make gpu-check ARGS="--device cpu --tiny"`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: test demo install clean gpu-check

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip >/dev/null
	$(BIN)/pip install -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

demo: $(STAMP)
	$(BIN)/warp-shape design

gpu-check:
	PYTHON=$(if $(wildcard $(BIN)/python),$(BIN)/python,$(PYTHON)) bash scripts/gpu_check.sh $(ARGS)

clean:
	rm -rf $(VENV) build *.egg-info out out.partial .out.lock
