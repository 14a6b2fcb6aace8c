# Two commands do all the set-up: `make demo` runs the main job, `make test` runs the test suite.
# Each creates .venv and installs the project on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test bench clean

$(BIN)/swarmctl: pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c constraints.txt -e '.[test]'
	touch $(BIN)/swarmctl

demo: $(BIN)/swarmctl
	$(BIN)/swarmctl demo --uavs 3 --seed 0 --out runs/demo

test: $(BIN)/swarmctl
	$(BIN)/python -m pytest -q

bench: $(BIN)/swarmctl
	$(BIN)/swarmctl bench

clean:
	rm -rf $(VENV) build *.egg-info
