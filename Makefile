# Two entry points for a fresh Debian/Ubuntu machine with Python 3.10+:
#   make demo   - simulate the demo scenario and run what the pipeline has on it
#   make test   - run the test suite
# Both create (or reuse) .venv and install everything the project needs, once.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEMO_OUT ?= demo_output

.PHONY: demo test bench clean system-deps

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
	$(PY) -m pip install --quiet -e ".[test]"
	@touch $(STAMP)

test: $(STAMP)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(PY) -m pytest -q

demo: $(STAMP)
	@bash scripts/ensure_system_deps.sh "$(PYTHON)"
	$(VENV)/bin/lidar3d demo --out $(DEMO_OUT)

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache
