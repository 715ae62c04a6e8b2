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

demo: venv
	$(BIN)/pe-mjx view --backend kinematic --arenas 4

test: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 \
	JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES=-1 $(BIN)/python -m pytest -q

bench: venv
	$(BIN)/pip install --quiet -e ".[dev,bench]"
	$(BIN)/python tools/bench_env.py

clean:
	rm -rf $(VENV)
