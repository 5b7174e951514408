# Two commands do everything on a fresh Debian machine: `make run` and `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: run test quick lint format bench screenshots clean system-deps

## Start the coordination server on http://localhost:8000 (prints the URLs to open).
run: $(STAMP)
	$(PY) -m crowdteleop serve

## Install what the tests need and run the whole suite (slow tests included).
test: $(STAMP)
	bash scripts/system-deps.sh test  # also starts PostgreSQL if it is down
	bash scripts/lerobot-venv.sh "$(PY)" >/dev/null  # LeRobot's own venv (cached; set-up, not test time)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/mypy  # src/, as configured in pyproject.toml (strict on the seams)
	CROWDTELEOP_PYTHON=$(PY) node --test tests/web/  # the pages' JS: schema validator, protocol, latency
	$(PY) -m pytest -n 2 --dist loadscope $(PYTEST_ARGS)  # a module per worker, Ray's first (tests/fixtures/schedule.py); timed tests alone

## The quick loop while coding: lint, types, and every test not marked slow.
quick: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/mypy
	$(PY) -m pytest -q -m "not slow" $(PYTEST_ARGS)

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/mypy
	$(VENV)/bin/ruff format --check src tests benchmarks

format: $(STAMP)
	$(VENV)/bin/ruff format src tests benchmarks
	$(VENV)/bin/ruff check --fix src tests benchmarks

bench: $(STAMP)
	$(PY) benchmarks/sim.py

## Refresh the README's pictures (docs/screenshots/) with the browser end-to-end tests.
screenshots: $(STAMP)
	CROWDTELEOP_SCREENSHOTS=docs/screenshots $(PY) -m pytest -q tests/e2e/test_web_e2e.py tests/e2e/test_phone_xr.py \
		tests/e2e/test_phone_camera.py tests/e2e/test_practice_page.py tests/e2e/test_vr_mode.py \
		tests/e2e/test_phone_layouts.py tests/e2e/test_admin_charts.py tests/e2e/test_workers_page.py \
		tests/e2e/test_review_page.py

system-deps:
	bash scripts/system-deps.sh test

# The venv is (re)built when pyproject.toml changes; otherwise this is a no-op.
$(STAMP): pyproject.toml scripts/system-deps.sh scripts/setup-venv.sh
	bash scripts/system-deps.sh test
	bash scripts/setup-venv.sh "$(PYTHON)" "$(VENV)"
	touch $(STAMP)

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
