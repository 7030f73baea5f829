# Entry points for a fresh Debian/Ubuntu machine with Python 3.10+:
#   make demo   - simulate the demo scenario and run what the pipeline has on it
#   make test   - the static checks (make lint: ruff lint and format check, mypy) and the test suite
#   make bench  - the evaluation suite (eval/run_suite.py): lidar3d beside KISS-ICP and GenZ-ICP on
#                 every simulated scenario; writes BENCHMARKS.md and eval/results/ (BENCH_ARGS to adjust)
#   make held-out - eval/held_out.py: five of the suite's layouts driven at other speeds, with other
#                 imperfections, on seeds the suite does not use (HELD_OUT_ARGS to adjust)
#   make fuzz   - the property-based parser tests (tests/test_fuzz_*.py) with FUZZ_EXAMPLES (10000) cases
#                 each instead of the suite's small budget; figures in docs/reliability.md
# Each creates (or reuses) .venv and installs everything it needs, once.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
DEMO_OUT ?= demo_output
BENCH_ARGS ?=
HELD_OUT_ARGS ?=
FUZZ_EXAMPLES ?= 10000
EVAL_STAMP := $(VENV)/.installed-eval

.PHONY: demo lint test bench held-out fuzz clean system-deps

all: test

system-deps:
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"

$(PY):
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(PYTHON) -m venv $(VENV)

# Reinstall only when the project's dependency list changes.
$(STAMP): pyproject.toml | $(PY)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	@touch $(STAMP)

# The test extra (pytest, evo as an independent metric oracle, ruff, mypy) and Ray for the batch
# engine test.
$(TEST_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e ".[test,ray]"
	@touch $(TEST_STAMP)

# Static checks, configured in pyproject.toml; any finding fails the target.
lint: $(TEST_STAMP)
	@echo "lint: ruff check (lint rules of [tool.ruff.lint]) on lidar3d eval tests"
	$(PY) -m ruff check lidar3d eval tests
	@echo "lint: ruff format --check (code formatting) on lidar3d eval tests"
	$(PY) -m ruff format --check lidar3d eval tests
	@echo "lint: mypy (static types, [tool.mypy]) on lidar3d"
	$(PY) -m mypy

test: $(TEST_STAMP) lint
	@bash scripts/ensure_system_deps.sh "$(PYTHON)" test
	$(PY) -m pytest -q

fuzz: $(TEST_STAMP)
	LIDAR3D_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(PY) -m pytest -q -p no:cacheprovider --hypothesis-show-statistics \
		tests/test_fuzz_*.py

demo: $(STAMP)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(VENV)/bin/lidar3d demo --out $(DEMO_OUT)

# The peers and the profiler are the optional `eval` extra, installed only for the benchmark, with the
# numeric stack held to the versions the published figures were measured with (eval/constraints.txt).
$(EVAL_STAMP): pyproject.toml eval/constraints.txt $(STAMP)
	$(PY) -m pip install --quiet -c eval/constraints.txt -e ".[eval]"
	@touch $(EVAL_STAMP)

bench: $(STAMP) $(EVAL_STAMP)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(PY) eval/run_suite.py $(BENCH_ARGS)

held-out: $(STAMP) $(EVAL_STAMP)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(PY) eval/held_out.py $(HELD_OUT_ARGS)

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .mypy_cache .ruff_cache
