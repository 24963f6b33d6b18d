# Set-up and the two commands README.md promises.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: run test test-all test-ci install clean bench

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

## make run: the whole pipeline on the bundled sample trial, into reports/sample/
run: $(STAMP)
	$(BIN)/vesselid run trials/sample/trial.toml --out reports/sample

## make test: the test suite without the slow regression runs (under 5 minutes on 2 cores)
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadscope -m "not slow"

## make test-all: the whole suite: make test, then the slow regression runs (pytest -m slow)
test-all: test-ci

## make test-ci: make test, then every slow run (what .ci/run calls); the regression module runs on its own
## with --dist loadgroup (its xdist_group marks are not honoured by pytest 9.2 + xdist 3.8: it schedules like load)
test-ci: test
	$(BIN)/python -m pytest -q -n 2 -m slow --dist loadscope --ignore=tests/test_regression_recovery.py
	$(BIN)/python -m pytest -q -n 2 -m slow --dist loadgroup tests/test_regression_recovery.py

bench: $(STAMP)
	$(BIN)/python benchmarks/ingest.py
	$(BIN)/python benchmarks/accuracy.py
	$(BIN)/python benchmarks/diagnose.py
	$(BIN)/python benchmarks/scaling.py

clean:
	rm -rf $(VENV) reports/sample
