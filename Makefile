# EVC Bench — the two commands a lab member needs: `make run` and `make test`.
# Each does its own set-up on a fresh machine (virtualenv and packages). `make test-fast` is the
# edit loop: the tests that are neither slow, real-time, browser nor PostgreSQL ones.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CORE_STAMP := $(VENV)/.core-stamp
STAMP  := $(VENV)/.installed-stamp
# The dashboard's charting library (uPlot, pinned in web/package-lock.json), served from web/node_modules.
WEB_STAMP := web/node_modules/.package-lock.json
# One BLAS thread: the least-squares solves are small and a 2-core lab PC thrashes with more.
export OPENBLAS_NUM_THREADS ?= 1
# Python's own default: each module's bytecode is cached (__pycache__) by the first process that
# imports it. An environment that sets PYTHONDONTWRITEBYTECODE makes every process (the test suite
# starts about a hundred: services, engines, clients, workers) compile all it imports from source.
unexport PYTHONDONTWRITEBYTECODE

# Every core works (pytest-xdist): a group of tests that shares an expensive module fixture
# (xdist_group) runs on one worker, the rest test by test; tests/conftest.py puts the long tests
# first (--no-loadscope-reorder keeps that order) so that the workers finish together.
PYTEST_WORKERS ?= auto
PYTEST_XDIST   := -n $(PYTEST_WORKERS) --dist loadgroup --no-loadscope-reorder
FAST_TESTS     := not slow and not realtime and not browser and not postgres

.PHONY: run test test-fast lint install clean browser

# --no-compile: pip would byte-compile all 12 000 modules of the packages (half its time); only
# those imported are compiled, once, when first imported (see PYTHONDONTWRITEBYTECODE above).
# In two steps: the service's own packages, then the test, report and lab tooling ('.[dev]'), so
# that `make test` can compile the kernels while the second step installs.
$(CORE_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet --no-compile -e .
	touch $(CORE_STAMP)

$(STAMP): $(CORE_STAMP)
	$(PY) -m pip install --quiet --no-compile -e '.[dev]'
	touch $(STAMP)

$(WEB_STAMP): web/package.json web/package-lock.json
	@command -v npm >/dev/null || { echo "npm is missing: install Node.js (20+) with npm for the dashboard's charts" >&2; exit 1; }
	cd web && npm ci --no-audit --no-fund --loglevel=error
	touch $(WEB_STAMP)

install: $(STAMP) $(WEB_STAMP)

## Debian's chromium for the browser tests (Playwright drives it; its own browser download is never used).
browser:
	bash tests/setup/install_browser.sh

## Start the service on 127.0.0.1:$(PORT) against the emulated bench, with its store in ./var. The
## default bench is paced to real time, as hardware is (EVCBENCH_BENCH=<name> picks another;
## `make run PORT=8001` another port).
PORT ?= 8000
run: $(STAMP) $(WEB_STAMP)
	$(VENV)/bin/evcbench serve --host 127.0.0.1 --port $(PORT) --data-dir var --bench "$${EVCBENCH_BENCH:-default_realtime}"

## Run every test (the 20 slowest are listed at the end, to keep the suite short). The store tests also run on PostgreSQL: this installs Debian's server if it is
## missing (EVCBENCH_SKIP_POSTGRES=1 skips that and those tests); the tests start their own cluster.
## While the test tooling, the dashboard's packages, PostgreSQL and the browser install, two
## processes compile the kernels into numba's cache (`evcbench warm`; logs in tests/artifacts/): on
## a fresh clone the two workers would otherwise each compile them at their start (22 s each).
## Once the test tooling is in, one collection (`pytest --collect-only`, beside the rest of the
## set-up and the lint) compiles the packages' bytecode and the tests' rewritten asserts, which
## each worker's first collection otherwise compiled for itself (19.8 s of CPU against 7.6 s).
WARM_LOG := tests/artifacts/warm
test: $(CORE_STAMP)
	@mkdir -p tests/artifacts; \
	$(VENV)/bin/evcbench warm emulator loop > $(WARM_LOG)-emulator.log 2>&1 & emulator=$$!; \
	$(VENV)/bin/evcbench warm models > $(WARM_LOG)-models.log 2>&1 & models=$$!; \
	$(MAKE) --no-print-directory $(STAMP) $(WEB_STAMP) && { $(PY) -m pytest --collect-only -q -p no:cacheprovider \
		> $(WARM_LOG)-collect.log 2>&1 & collect=$$!; } && bash tests/setup/install_postgres.sh \
		&& bash tests/setup/install_browser.sh; setup=$$?; \
	failed=0; \
	wait $$emulator || failed=1; \
	wait $$models || failed=1; \
	cat $(WARM_LOG)-emulator.log $(WARM_LOG)-models.log; \
	[ $$setup -eq 0 ] || exit $$setup; \
	[ $$failed -eq 0 ] || { echo "evcbench warm failed (above)" >&2; exit 1; }; \
	$(MAKE) --no-print-directory lint; lint=$$?; \
	wait $$collect; \
	[ $$lint -eq 0 ] || exit $$lint
	$(PY) -m pytest -q $(PYTEST_XDIST) --durations=20

## The lint gate (part of `make test`): ruff's lint and format check, and the import-linter contracts
## that hold the layers (pyproject.toml, [tool.importlinter]).
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports

## The edit loop: the same, less the tests marked slow, realtime, browser or postgres (pyproject.toml).
test-fast: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_XDIST) -m "$(FAST_TESTS)"

clean:
	rm -rf $(VENV) var .pytest_cache tests/artifacts web/node_modules
