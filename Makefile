# Two commands: `make demo` (main job) and `make test` (the suite). Each creates .venv itself.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: venv demo test lint bench clean

$(BIN)/pe-mjx: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $@

venv: $(BIN)/pe-mjx

# The live viewer with the shipped learned teams (MIX pursuers and evaders, 3M env steps).
demo: venv
	$(BIN)/pe-mjx view --backend kinematic --arenas 4 --pursuers mix-20-5-8-3m --evaders mix-20-5-8-3m

# Two pytest workers, one test file each at a time (module fixtures stay in one process): most
# of the suite compiles (one core each) or waits on subprocesses, so two halve its wall time.
test: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 \
	JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES=-1 $(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=25

bench: venv
	$(BIN)/pip install --quiet -e ".[dev,bench]"
	$(BIN)/python tools/bench_env.py

clean:
	rm -rf $(VENV)
