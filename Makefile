# Monte: `make render` sets everything up (first time) and renders the Cornell box; `make test` runs the tests.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SPP ?= 64

.PHONY: setup render test test-slow test-all bench crosscheck extension clean

$(STAMP): requirements.txt pyproject.toml
	$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "Monte needs Python 3.11 (bpy 5.0 requires it); set PYTHON=/path/to/python3.11")'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.txt
	$(BIN)/python -m pip install --quiet --no-deps -e .
	touch $(STAMP)

setup: $(STAMP)

render: $(STAMP)
	$(BIN)/monte render cornell -o cornell.exr --spp $(SPP)

test: $(STAMP)
	$(BIN)/python -m pytest -m "not slow" -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow -q

test-all: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/monte bench

# The feature-by-feature Cycles cross-check at 64x64 and 4x the samples of the default suite's (about 20 min
# on 2 cores).
crosscheck: $(STAMP)
	$(BIN)/python -m pytest tests/test_crosscheck.py -m slow -q -rA

extension: $(STAMP)
	$(BIN)/python tools/build_extension.py

clean:
	rm -rf $(VENV) dist build *.egg-info cornell.exr cornell.png
