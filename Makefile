# Quick start: `make demo` and `make test` (see README.md).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
CDGPS  := $(VENV)/bin/cdgps
DEMO   := build/demo

.PHONY: demo test venv clean bench studies paper

$(VENV)/.installed: pyproject.toml setup.py cdgps_cli/estimation/_ekfcore.c cdgps_cli/estimation/_lambdacore.c cdgps_cli/tracking/_trackcore.c cdgps_cli/io/_ubxcore.c cdgps_cli/model/gps/_orbitcore.c
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

venv: $(VENV)/.installed

# the suite on up to 4 cores (pytest-xdist; a test file stays on one worker, so its module fixtures run once).
# Bytecode caching on even where the environment turns it off (PYTHONDONTWRITEBYTECODE): the suite starts
# hundreds of `cdgps` processes, each would recompile the package (tests/cli: 17.1 s -> 12.0 s wall on 2 cores).
# The 15 slowest tests over 5 s are listed at the end, so a CI log shows where the suite's time goes.
# Where the workers take every CPU, the commands compute a pair's two receivers in turn, not forked beside (tests/conftest.py).
test: venv
	env -u PYTHONDONTWRITEBYTECODE $(PY) -m pytest -q -n logical --maxprocesses 4 --dist loadfile --durations=15 --durations-min=5

demo: venv
	bash scripts/demo.sh $(CDGPS) $(DEMO)

bench: venv
	$(PY) -m pip install --quiet -e '.[bench]'
	$(PY) benchmarks/bench_foundation.py
	$(PY) benchmarks/bench_init.py
	$(PY) benchmarks/bench_estimate.py
	$(PY) benchmarks/bench_spectra.py
	$(PY) benchmarks/bench_memory.py
	$(PY) benchmarks/bench_io.py
	$(PY) benchmarks/bench_gnss_pipeline.py

# long studies (tens of minutes on 2 cores): integer-fix success table, accuracy reports
studies: venv
	$(PY) -m pip install --quiet -e '.[bench]'
	$(PY) benchmarks/init_success.py
	$(PY) benchmarks/estimate_accuracy.py
	$(PY) benchmarks/oma_crosscheck.py
	$(PY) benchmarks/long_records.py --hours 1 3 6 24 --out docs/benchmarks/long_records.json
	$(PY) benchmarks/record_length.py

# every headline of the three papers, reproduced: docs/paper-reproduction.md (≈ 3 min on 2 quiet cores: 177 s wall, 275 s CPU)
paper: venv
	$(PY) benchmarks/paper.py

clean:
	rm -rf build $(VENV)
