# handradar: every target sets itself up (a .venv in the repo, created when missing).
SHELL := /bin/bash
.DEFAULT_GOAL := help

BOOT_PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV        := .venv
PY          := $(VENV)/bin/python
STAMP       := $(VENV)/.installed
JOBS        ?= 2
ARGS        ?=
WORLD       ?= default
SIZE        ?= 240
COMMA       := ,

.PHONY: help install smoke run test test-full bench sweep data-efficiency data-efficiency-figure measured tables mlflow-ui world world-gallery gap-benchmark gap-report fetch-data prune-cache clean

help: ## list the targets
	@grep -E '^[a-zA-Z0-9_-]+:.*## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*## "}; {printf "  make %-26s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@test -x $(PY) || $(BOOT_PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade --quiet pip
	$(PY) -m pip install --quiet -e '.[dev,slurm]'
	@touch $(STAMP)

install: $(STAMP) ## create .venv and install handradar (editable) with its test tools

smoke: $(STAMP) ## the whole pipeline on a 60-recording world in about 1 min: a table and a figure (a check, not results)
	$(PY) train.py +experiment=few_shot_5pct +debug=smoke $(ARGS)

run: $(STAMP) ## the paper's 5 %* comparison on the reference world (about 9 min cold, 4 warm): a table and a figure
	$(PY) train.py +experiment=few_shot_5pct $(ARGS)

SFINGE3D_HERE = test -d data/sfinge3d/Dictionary || test -d $${HANDRADAR_SHARED:-../shared}/data/sfinge3d/Dictionary

test: $(STAMP) ## the default test suite (fast; excludes @slow); fetches SFINGE3D once where it is missing
	@$(SFINGE3D_HERE) || $(MAKE) --no-print-directory fetch-data || echo "SFINGE3D could not be fetched: its tests skip (make fetch-data)"
	$(PY) -m pytest -n $(JOBS) -q $(ARGS)

test-full: $(STAMP) ## every test, slow ones included
	@$(SFINGE3D_HERE) || $(MAKE) --no-print-directory fetch-data || echo "SFINGE3D could not be fetched: its tests skip (make fetch-data)"
	$(PY) -m pytest -n $(JOBS) -q -m "" $(ARGS)

bench: $(STAMP) ## benchmarks: throughput figures and ratios (benchmarks/results.md)
	$(PY) -m benchmarks $(ARGS)

sweep: $(STAMP) ## the paper's few-shot grid over seeds (Hydra multirun, joblib launcher)
	$(PY) train.py -m hydra/launcher=joblib +experiment=few_shot_5pct,few_shot_20pct,few_shot_50pct variants=all seed=1,2,3 $(ARGS)

data-efficiency: $(STAMP) ## the data-efficiency runs: 1-36 real rows per gesture x seeds 1-3, and the paper's simulator
	$(PY) train.py -m hydra/launcher=joblib +experiment=data_efficiency seed=1,2,3 split.per_class=1,2,4,8,16,36 threads=1 $(ARGS)
	$(PY) train.py -m hydra/launcher=joblib +experiment=data_efficiency 'variants=[radar_pool]' seed=1,2,3 threads=1 $(ARGS)
	$(PY) train.py -m hydra/launcher=joblib +experiment=data_efficiency 'variants=[enhanced_synth]' seed=1,2,3 split.per_class=1,2,4,8,16,36 threads=1 $(ARGS)
	$(PY) train.py -m hydra/launcher=joblib +experiment=data_efficiency synth.fit_sim=none 'variants=[model_synth_only]' seed=1,2,3 threads=1 $(ARGS)

measured: $(STAMP) ## measured radar (Xia et al.): K = 0-all real rows per class x seeds 1-3, 2 jobs at a time (MANIFEST=FILE: another dataset)
	$(PY) train.py -m hydra/launcher=joblib +experiment=measured $(if $(MANIFEST),data.manifest=$(MANIFEST),) split.per_class=0,1,2,4,8,16,50,all seed=1,2,3 threads=1 trainer.enable_progress_bar=false $(ARGS)

data-efficiency-figure: $(STAMP) ## the data-efficiency curve (docs/figures/data_efficiency.png) from the MLflow runs
	$(PY) -m experiments.data_efficiency $(ARGS)

tables: $(STAMP) ## docs/results.md (every row with its command, commit, seeds, machine) + CSV tables from the MLflow runs
	$(PY) -m experiments.tables $(ARGS)

mlflow-ui: $(STAMP) ## the MLflow dashboard on http://127.0.0.1:5000; first prints each experiment's link (opens it as model training)
	@$(PY) -m handradar.runs.mlflow sqlite:///$(CURDIR)/logs/mlflow/mlflow.db http://127.0.0.1:5000
	$(VENV)/bin/mlflow ui --backend-store-uri sqlite:///$(CURDIR)/logs/mlflow/mlflow.db --host 127.0.0.1 --port 5000

world: $(STAMP) ## write reference-world recordings to data/world_recordings
	$(VENV)/bin/handradar-world out=data/world_recordings $(ARGS)

world-gallery: $(STAMP) ## PNG grid of reference-world spectrograms per gesture and per effect
	$(PY) -m handradar.viz.world_gallery $(ARGS)

gap-benchmark: $(STAMP) ## the withheld-effect validation of the gap diagnosis: WORLD=default|heldout|heldout2|heldout3 SIZE=240|36 (comma lists: one multirun)
	$(PY) diagnose.py $(if $(findstring $(COMMA),$(WORLD)$(SIZE)),-m,) +experiment=gap_benchmark world=$(WORLD) benchmark.size=$(SIZE) $(ARGS)

gap-report: $(STAMP) ## the gap benchmark's summary table from results/gap_benchmark/*.json (writes docs/gap_report.md)
	$(PY) -m experiments.gap_report $(ARGS)

fetch-data: $(STAMP) ## SFINGE3D into data/sfinge3d (git clone; DHG: handradar-fetch dataset=dhg fetch.url=URL)
	$(VENV)/bin/handradar-fetch dataset=sfinge3d $(ARGS)

prune-cache: ## delete the per-bone slot profiles in .cache/ (most of its size; recomputed when a job needs them); not while jobs run
	@du -sh .cache 2>/dev/null || true
	find .cache \( -name 'slot_profiles-*.h5' -o -name '.slot_profiles-*.part' \) -delete 2>/dev/null || true
	@du -sh .cache 2>/dev/null || true

clean: ## remove caches, logs and build files (keeps .venv)
	rm -rf .cache logs outputs multirun .pytest_cache .hypothesis build *.egg-info src/*.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
