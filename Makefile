# Two commands do all the set-up on a fresh machine with Python 3.11 and pip:
#   make run   - create .venv, install, run the default workflow, print where the report is
#   make test  - same bootstrap, run the test suite
# Further targets: lint (snakemake --lint, snakefmt --check), crosscheck (ross, separate heavy environment), bench.

PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ROSS_VENV := .venv-ross
ROSS_STAMP := $(ROSS_VENV)/.installed
CORES ?= 2

.PHONY: run test lint crosscheck bench clean

$(STAMP): requirements.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $@

run: $(STAMP)
	$(BIN)/python -m compileall -q workflow/ambid
	$(BIN)/snakemake --cores $(CORES)
	@echo "Reports (one self-contained HTML page per machine; tables and figures under results/<machine>/):"
	@for machine in $$($(BIN)/python -c "import yaml; print(*yaml.safe_load(open('config/config.yaml'))['machines'])"); do \
		echo "  $(CURDIR)/results/$$machine/report.html"; done

# The tests on every core (pytest-xdist; tests that share one expensive fixture run on one worker, see
# tests/conftest.py), one BLAS thread per worker so the workers do not fight over the cores.  compileall: the
# library's bytecode is written once here, so every Snakemake job reads it even where PYTHONDONTWRITEBYTECODE is set.
# --durations: the slowest tests are listed at the end, so a CI log shows where the suite's time goes.
test: $(STAMP)
	$(BIN)/python -m compileall -q workflow/ambid
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -n $(CORES) --dist loadgroup --durations=15

lint: $(STAMP)
	$(BIN)/snakemake --lint
	$(BIN)/snakefmt --check Snakefile rules

$(ROSS_STAMP): requirements-ross.txt pyproject.toml
	$(PYTHON) -m venv $(ROSS_VENV)
	$(ROSS_VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r requirements-ross.txt
	$(ROSS_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $@

crosscheck: $(ROSS_STAMP)
	$(ROSS_VENV)/bin/python -m pytest tests/crosscheck

bench: $(STAMP) $(ROSS_STAMP)
	$(ROSS_VENV)/bin/python benchmarks/bench_rotor.py
	$(BIN)/python benchmarks/bench_identification.py
	$(BIN)/python benchmarks/bench_fit.py
	$(BIN)/python benchmarks/bench_update.py
	$(BIN)/python benchmarks/bench_diagnose.py
	$(BIN)/python benchmarks/bench_floor.py
	$(BIN)/python benchmarks/bench_foreign_logs.py
	$(BIN)/python benchmarks/bench_extrapolation.py
	$(BIN)/python benchmarks/bench_amplitude_limit.py

clean:
	rm -rf results logs .snakemake
