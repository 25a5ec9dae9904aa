# One command sets up and runs; one command sets up and tests. Both create .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[service,dev]"
	touch $(STAMP)

run: $(STAMP)  # make run PORT=8001 ZENOH_PORT=7448: the HTTP and Zenoh ports (loopback)
	$(BIN)/python -m sim_worker.warm_up
	$(BIN)/contact-skills up $(if $(PORT),--port $(PORT)) $(if $(ZENOH_PORT),--zenoh-port $(ZENOH_PORT))

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m sim_worker.warm_up  # numba: compile once here, not in every test's worker
	$(BIN)/pytest -q -n 2 --dist loadfile  # two processes: one per core; a test file stays in one process

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_learning.py

clean:
	rm -rf $(VENV) .pytest_cache
