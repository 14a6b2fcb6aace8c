# Two commands do all the set-up: `make demo` runs the main job, `make test` runs the test suite.
# Each creates .venv and installs the project on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench clean

$(BIN)/swarmctl: pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c constraints.txt -e '.[test]'
	touch $(BIN)/swarmctl

demo: $(BIN)/swarmctl
	rm -rf runs/demo.previous; if [ -d runs/demo ]; then mv runs/demo runs/demo.previous; fi  # the last run is kept
	$(BIN)/swarmctl demo --uavs 3 --seed 0 --out runs/demo

test: $(BIN)/swarmctl
	$(BIN)/ruff check swarmctl tests tools
	$(BIN)/ruff format --check swarmctl tests tools
	$(BIN)/python tools/type_counts.py && $(BIN)/mypy
	$(BIN)/python -m pytest -q

lint: $(BIN)/swarmctl
	$(BIN)/ruff check --fix swarmctl tests tools
	$(BIN)/ruff format swarmctl tests tools

bench: $(BIN)/swarmctl
	$(BIN)/swarmctl bench

clean:
	rm -rf $(VENV) build *.egg-info
