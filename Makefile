# epoet: every target that needs the environment depends on `install`, so each command in the
# README works on a fresh machine that has only Python 3.11 and make.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install test typecheck docs-strict pytest docs train gallery tables figures compute paper epoet-sac-starts reference records suite bench bench-learning clean-venv

install: $(STAMP)

# Re-runs pip only when the dependency files change; a second `make install` is a no-op.
$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[dev]'
	touch $(STAMP)

# Style first (ruff format and import order: seconds, and a failure stops here); then mypy on
# epoet/, analysis/, pipeline/ (the paths and options are pyproject.toml's) and the
# documentation's strict build run beside pytest, so CI checks them too: each keeps one core busy
# for up to half a minute, which run one after the other left the second core idle.
# pytest: one test process per core; a file's tests share a process (module fixtures run once,
# and the Ray tests, which stop every Ray process on the machine, never overlap one another); the
# longest files first (tests/conftest.py LONGEST_FIRST). Each part can be run alone too; here
# `-o $(STAMP)` tells the inner make the install is done (it does not pass on the outer -o).
test: install
	$(PY) -m ruff format --check epoet analysis pipeline tests
	$(PY) -m ruff check epoet analysis pipeline tests
	$(MAKE) --no-print-directory -o $(STAMP) -j3 typecheck docs-strict pytest

typecheck: install
	$(PY) -m mypy

docs-strict: install
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --quiet

pytest: install
	$(PY) -m pytest -q -n auto --dist loadfile --no-loadscope-reorder --durations=10 tests

# The documentation site (mkdocs.yml, pages under docs/) into site/, strictly: a broken link, a
# missing page or an unknown anchor fails the build. `.venv/bin/mkdocs serve` previews it.
# (NO_MKDOCS_2_WARNING: Material's notice about MkDocs 2, which pyproject.toml keeps out.)
docs: install
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

# The main job (see README): one laptop-scale ePOET run, tracked in ./mlflow.db.
train: install
	$(PY) -m epoet

# The paper's tables and figures from the runs in ./mlflow.db (EXPERIMENT: its experiment;
# default: the runs' default, tracking.experiment; SUITE: the suite whose evaluations they read,
# a name (shipped, paper) or a folder; default: shipped). RECORDS=docs/results/<name>: the tables
# from those evaluation records instead of the store (python -m pipeline.records writes them).
# Both write to results/<input>/<suite>/, <input> being the experiment or the records folder's
# name (e.g. results/epoet/shipped/table1_shipped.md, results/workstation/paper/iqm_paper.png),
# so two inputs never overwrite each other's files.
EXPERIMENT ?=
SUITE ?=
RECORDS ?=
tables: install
	$(PY) -m analysis.tables $(if $(RECORDS),--records $(RECORDS),$(if $(EXPERIMENT),--experiment $(EXPERIMENT))) $(if $(SUITE),--suite $(SUITE))

# RECORDS=docs/results/<name>: success against CPU hours and the learning curves from those
# records alone (analysis.success_vs_compute; SUITE default: paper), into
# results/compute/<name>/<suite>/.
figures: install
	$(if $(RECORDS),$(PY) -m analysis.success_vs_compute --records $(RECORDS) $(if $(SUITE),--suite $(SUITE)),$(PY) -m analysis.figures $(if $(EXPERIMENT),--experiment $(EXPERIMENT)) $(if $(SUITE),--suite $(SUITE)))

# Success against compute: evaluate the CPU-time snapshots of RUNS (run folders, still training
# or finished) on the paper and shipped suites into the records folder RECORDS
# (pipeline.snapshots).
RUNS ?=
compute: install
	$(PY) -m pipeline.snapshots --runs $(RUNS) --out $(RECORDS) $(OVERRIDES)

# Every algorithm x seed at one budget, evaluated, tabled and plotted; resumable
# (docs/analysis.md). At a CPU-hour budget (workstation) each run's CPU-time snapshots are
# evaluated as its job ends, into RECORDS (default results/paper-<budget>/records), and the report
# comes from those records; otherwise RECORDS=docs/results/<name> also exports the evaluated runs
# there. JOBS: jobs at a time (default: one per core); RUNS_DIR: where the job folders go.
BUDGET ?= laptop
SEEDS  ?= 1,2,3
JOBS   ?=
SUITES ?=
RUNS_DIR ?=
OVERRIDES ?=
paper: install
	$(PY) -m pipeline.paper --budget $(BUDGET) --seeds $(SEEDS) $(if $(JOBS),--jobs $(JOBS)) $(if $(SUITES),--suites $(SUITES)) $(if $(RECORDS),--records $(RECORDS)) $(if $(RUNS_DIR),--runs $(RUNS_DIR)) $(OVERRIDES)

# ePOET-SAC's three starts (cold, a SAC run of ours, the authors' SAC) x SEEDS at the workstation
# budget, evaluated on both suites, tabled, records in docs/results/epoet-sac-starts
# (docs/algorithms/epoet-sac.md); resumable. SAC_RUN=<run folder | MLflow run id>: the SAC run of ours (default:
# trained first).
SAC_RUN ?=
epoet-sac-starts: install
	$(PY) -m pipeline.epoet_sac_starts --seeds $(SEEDS) $(if $(JOBS),--jobs $(JOBS)) $(if $(SAC_RUN),--sac-run $(SAC_RUN)) $(OVERRIDES)

# The evaluated runs of EXPERIMENT as evaluation records in RECORDS (docs/results/README.md).
records: install
	$(PY) -m pipeline.records --experiment $(EXPERIMENT) --out $(RECORDS)

# The authors' published agents (read from their files: docs/authors.md) on the paper's suite, tabled (results/reference/);
# RECORDS=docs/results/reference also exports their evaluation records.
reference: install
	$(PY) -m pipeline.reference $(if $(RECORDS),--records $(RECORDS))

# Check the shipped evaluation suite against a fresh regeneration (seconds: docs/RESULTS.md).
suite: install
	$(PY) -m epoet.eval.suite check=true

gallery: install
	$(PY) -m epoet.eval.gallery terrain=cppn n=8 out=gallery

bench: install
	$(PY) bench/env_throughput.py
	$(PY) bench/rollout_throughput.py
	$(PY) bench/es_scaling.py
	$(PY) bench/sac_updates.py
	$(PY) bench/integrators.py
	$(PY) bench/epoet_iteration.py

# Learning per iteration and per second with each integrator (about 15 minutes).
bench-learning: install
	$(PY) bench/integrator_learning.py

clean-venv:
	rm -rf $(VENV)
