# One command sets up and runs; one command sets up and tests. Both create .venv first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean browser

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[service,dev]"
	touch $(STAMP)

run: $(STAMP)  # make run PORT=8001 ZENOH_PORT=7448: the HTTP and Zenoh ports (loopback)
	$(BIN)/contact-skills warm-up
	$(BIN)/contact-skills up $(if $(PORT),--port $(PORT)) $(if $(ZENOH_PORT),--zenoh-port $(ZENOH_PORT))

# The dashboard's browser tests drive Debian's Chromium (tests/test_dashboard.py): installed here where this user can
# (root with apt-get); elsewhere the line below says how, and those tests skip (CI sets CONTACT_SKILLS_REQUIRE_BROWSER=1:
# there they fail instead).
browser:
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
	  && { DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1 \
	    || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }; }; } \
	  || echo "chromium is not installed (as root: apt-get install chromium): the dashboard's browser tests skip"

test: $(STAMP) browser
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/contact-skills warm-up  # numba: compile once here, not in every test's worker
	$(BIN)/pytest -q -rs -n 2 --dist loadfile  # two processes: one per core; a test file stays in one process

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# Every benchmark in its documented (full) mode, one after the other: each rewrites its own section of
# docs/BENCHMARKS.md (the corpus, force-source, KU Leuven truth and work-piece ones: docs/LEARNING.md; the contours one:
# docs/RESULTS.md) with the machine and its load. Long on 2 shared cores: run it on a quiet machine.
# make test runs each one's --smoke instead (tests/test_benchmarks_smoke*.py).
bench: $(STAMP)
	$(BIN)/pip install --quiet movement-primitives pytransform3d  # bench_dmp_peer's peer, for this target only
	$(BIN)/contact-skills warm-up
	$(BIN)/python benchmarks/bench_learning.py
	$(BIN)/python benchmarks/bench_kinesthetic.py
	$(BIN)/python benchmarks/bench_corpus.py
	$(BIN)/python benchmarks/bench_learning_sources.py
	$(BIN)/python benchmarks/bench_joint_learning.py
	$(BIN)/python benchmarks/bench_gain_schedule.py
	$(BIN)/python benchmarks/bench_kuleuven_truth.py
	$(BIN)/python benchmarks/bench_work_piece.py
	$(BIN)/python benchmarks/bench_real_skills.py
	$(BIN)/python benchmarks/bench_kuleuven_cad.py
	$(BIN)/python benchmarks/bench_contours.py
	$(BIN)/python benchmarks/bench_verdicts.py
	$(BIN)/python benchmarks/bench_toolchain.py
	$(BIN)/python benchmarks/bench_dmp_peer.py
	$(BIN)/python benchmarks/bench_control_loop.py --repeats 5
	$(BIN)/python benchmarks/bench_mujoco_loop.py
	$(BIN)/python benchmarks/bench_engines.py
	$(BIN)/python benchmarks/bench_telemetry.py
	$(BIN)/python benchmarks/bench_service.py
	$(BIN)/python benchmarks/bench_service_load.py
	$(BIN)/python benchmarks/bench_sweeps.py
	$(BIN)/python benchmarks/bench_dashboard.py
	$(BIN)/python benchmarks/bench_long_run.py
	$(BIN)/python benchmarks/bench_worker_memory.py
	$(BIN)/python benchmarks/bench_floods.py

clean:
	rm -rf $(VENV) .pytest_cache
