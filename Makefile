# Quick start: `make demo` and `make test` (see README.md).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CDGPS  := $(VENV)/bin/cdgps
DEMO   := build/demo

.PHONY: demo test venv clean bench

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

venv: $(VENV)/.installed

test: venv
	$(PY) -m pytest -q

demo: venv
	bash scripts/demo.sh $(CDGPS) $(DEMO)

bench: venv
	$(PY) benchmarks/bench_foundation.py

clean:
	rm -rf build $(VENV)
