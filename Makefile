# EVC Bench — the two commands a lab member needs: `make run` and `make test`.
# Each does its own set-up on a fresh machine (virtualenv and packages).

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

## Start the service on 127.0.0.1:8000 against the emulated bench, with its store in ./var.
run: $(STAMP)
	$(VENV)/bin/evcbench serve --host 127.0.0.1 --port 8000 --data-dir var

## Run every test.
test: $(STAMP)
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) var .pytest_cache tests/artifacts
