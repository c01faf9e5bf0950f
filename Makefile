# make demo: fresh machine -> venv, install, train Hopper-v5 with the default preset, evaluate, print the score.
# make lint: ruff (lint and format check) and mypy, which must report nothing.
# make test: fresh machine -> venv, install, lint, run the whole suite in two worker processes (pytest-xdist): one
# compiles or waits on a child process while the other computes, so on two cores pytest takes 0.74-0.80 of the time
# one process takes (583 and 630 s against 785 s, 2026-11-30; pytest alone, once installed). The whole of `make test`
# on a clean clone, as `bash .ci/run` runs it (venv, install, lint, suite), took about 11.5 minutes that day, 582 s of
# it pytest; on slower runs of the same machine pytest alone took 1,015-1,207 s, with both cores busy throughout.
# make test-fast: lint, then the suite without the slow tests (pytest -m "not slow"): the unit tests, in under 2 minutes.
# make test-heavy: only the tests that make test leaves out for time (the MJX ports of the larger envs).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
DEMO_DIR ?= runs/demo

.PHONY: install lint test test-fast test-heavy demo bench clean docs

install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q pip==26.3
	$(PY) -m pip install -q -e ".[test]"
	touch $@

# The demo needs canter alone, not the test tools and the extras they cover.
$(VENV)/.installed-core: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q pip==26.3
	$(PY) -m pip install -q -e .
	touch $@

lint: install
	$(VENV)/bin/ruff check src tests benchmarks && $(VENV)/bin/ruff format --check src tests benchmarks && $(VENV)/bin/mypy

test: lint
	$(PY) -m pytest -q -n 2 --durations=15

test-fast: lint
	$(PY) -m pytest -q -n 2 -m "not slow"

test-heavy: install
	$(PY) -m pytest -q -n 2 --run-heavy -m heavy

demo: $(VENV)/.installed-core
	rm -rf $(DEMO_DIR)
	$(VENV)/bin/canter train Hopper-v5 --seed 0 --total-steps 2.5e6 --out-dir $(DEMO_DIR)
	$(VENV)/bin/canter eval $$(ls -d $(DEMO_DIR)/*/ | head -n 1) --episodes 10

docs: install
	$(PY) -m canter.docs README.md

bench: install
	bash benchmarks/ppo_speed/run.sh

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info .mypy_cache .ruff_cache
