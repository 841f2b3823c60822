# Two commands: `make run` (the demo session, then the paper report) and `make test` (the suite).
# Both create .venv on first use through the one idempotent `.venv` target.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean-venv
$(STAMP): setup.py setup.cfg package.xml Makefile
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[ros,record,viz,test,study]'
	touch $(STAMP)

.venv: $(STAMP)

run: .venv
	$(BIN)/panel-rig demo
	$(BIN)/panel-rig paper --out out/paper

test: .venv
	$(BIN)/python -m ruff check panel_rig tests benchmarks
	$(BIN)/python -m pytest -q tests

bench: .venv
	$(BIN)/python benchmarks/run.py

clean-venv:
	rm -rf $(VENV)
