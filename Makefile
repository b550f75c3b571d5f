# Two entry points for a fresh machine: `make demo` and `make test`. Both set up .venv/ first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test lint bench clean

setup: $(STAMP)

$(STAMP): requirements.txt requirements-node.txt constraints.txt setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.txt -c constraints.txt
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: setup
	$(VENV)/bin/hjrno demo --out out/demo

test: setup
	$(PY) -m pytest -q -n 2 --dist loadgroup test  # real-time tests on one worker: test/conftest.py

lint: setup
	$(VENV)/bin/ruff check .

bench: setup
	$(VENV)/bin/hjrno bench solver --out benchmarks/results

clean:
	rm -rf out build install log
